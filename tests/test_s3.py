"""The lake on object storage: a moto S3 server on 127.0.0.1, the real CLIs as subprocesses."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from tests.conftest import BIN, GRID, dataset_files, failed_in_one_line, local_files
from tests.servers import free_port, moto_s3, remote_files, s3fs_for, stop_group

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    with moto_s3(tmp_path_factory.mktemp("moto") / "moto.log") as env:
        yield env


def cli(env: dict[str, str], *args, timeout: float = 300) -> subprocess.CompletedProcess:
    cmd = [str(BIN / str(args[0])), *map(str, args[1:])]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, **env})


def test_grid_all_modes_on_s3_equal_local_and_read_back(s3, grid_lake, tmp_path):
    lake = "s3://lake/grid"
    gen = cli(s3, "smgen", "generate", *GRID, "--mode", "all", "--lake", lake)
    assert gen.returncode == 0, gen.stderr
    assert gen.stdout.count("written") == 3
    remote, local = remote_files(s3, "lake/grid"), local_files(grid_lake)
    for mode in ("MEM", "MM", "MME"):
        ds = f"grid-seed3-{mode}"
        got, want = dataset_files(remote, ds), dataset_files(local, ds)
        assert got.keys() == want.keys() and len(got) == 5  # 3 shards, regular sampling, manifest
        for name in want:  # shards, regular file and manifest alike: the same bytes
            assert got[name] == want[name], name
    assert "catalog.parquet" in remote

    listing = cli(s3, "smgen", "ls", "--lake", lake, "--json")
    assert listing.returncode == 0, listing.stderr
    assert sorted(json.loads(line)["id"] for line in listing.stdout.splitlines()) == [
        "grid-seed3-MEM",
        "grid-seed3-MM",
        "grid-seed3-MME",
    ]
    info = cli(s3, "smgen", "info", "grid-seed3-MM", "--lake", lake, "--json")
    assert info.returncode == 0 and json.loads(info.stdout)["path"] == "s3://lake/grid/grid-seed3-MM"
    ok = cli(s3, "smgen", "validate", "grid-seed3-MEM", "s3://lake/grid/grid-seed3-MME", "--lake", lake)
    assert ok.returncode == 0 and ok.stdout.split() == ["grid-seed3-MEM:", "ok", "grid-seed3-MME:", "ok"], ok.stdout

    # validate fetches the objects: a flipped byte in the middle of a shard is found remotely
    fs = s3fs_for(s3)
    key = "lake/grid/grid-seed3-MM/shard-00001.mcap"
    good = fs.cat_file(key)
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF
    fs.pipe_file(key, bytes(bad))
    try:
        broken = cli(s3, "smgen", "validate", "grid-seed3-MM", "--lake", lake)
        assert broken.returncode == 1 and "shard-00001.mcap: sha256 differs" in broken.stdout
    finally:
        fs.pipe_file(key, good)

    export = cli(
        s3,
        "smgen",
        "export",
        "grid-seed3-MM",
        "--lake",
        lake,
        "--format",
        "parquet",
        "--out",
        tmp_path / "mm.parquet",
        "--limit",
        100,
    )
    assert export.returncode == 0, export.stderr


def test_training_from_s3_equals_training_from_the_folder(s3, grid_lake, tmp_path):
    lake = "s3://lake/train"
    assert cli(s3, "smgen", "generate", *GRID, "--mode", "MME", "--lake", lake).returncode == 0
    common = ["--steps", 200, "--eval-every", 100, "--batch-size", 64, "--threads", 1]
    remote = cli(s3, "smtrain", "fit", f"{lake}/grid-seed3-MME", *common, "--out", tmp_path / "remote")
    local = cli(s3, "smtrain", "fit", grid_lake / "grid-seed3-MME", *common, "--out", tmp_path / "local")
    assert remote.returncode == 0, remote.stderr
    assert local.returncode == 0, local.stderr
    # the same losses and metrics, to the last digit printed
    assert remote.stdout.splitlines()[-1] == local.stdout.splitlines()[-1]
    config = json.loads((tmp_path / "remote" / "config.json").read_text())
    assert config["dataset"] == f"{lake}/grid-seed3-MME"
    import pyarrow.parquet as pq

    a, b = (
        pq.read_table(tmp_path / name / "metrics.parquet").drop_columns(["elapsed_s"]) for name in ("remote", "local")
    )
    assert a.num_rows == 3 and json.dumps(a.to_pylist()) == json.dumps(b.to_pylist())  # NaN-safe, bit for bit


def _wait_for(predicate, timeout: float = 120, every: float = 0.2):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(every)


def test_killed_generation_on_s3_is_invisible_then_completes_byte_identically(s3, tmp_path):
    args = ["--setup", "grid", "--mode", "MEM", "--transitions", "24000", "--shard-size", "1000", "--seed", "7"]
    lake, fs = "s3://lake/killed", s3fs_for(s3)
    proc = subprocess.Popen(
        [str(BIN / "smgen"), "generate", *args, "--workers", "1", "--lake", lake],
        env={**os.environ, **s3},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        _wait_for(lambda: len(fs.glob("lake/killed/grid-seed7-MEM/shard-*", refresh=True)) >= 3)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        stop_group(proc)
    shards = fs.glob("lake/killed/grid-seed7-MEM/shard-*", refresh=True)
    assert 3 <= len(shards) < 24 and not fs.exists("lake/killed/grid-seed7-MEM/manifest.json")
    listing = cli(s3, "smgen", "ls", "--lake", lake, "--json")
    assert listing.returncode == 0 and listing.stdout == ""
    info = cli(s3, "smgen", "info", "grid-seed7-MEM", "--lake", lake)
    assert info.returncode == 2 and "incomplete" in info.stderr
    fit = cli(s3, "smtrain", "fit", f"{lake}/grid-seed7-MEM", "--steps", 10, "--out", tmp_path / "run")
    assert fit.returncode == 2 and "incomplete" in fit.stderr

    again = cli(s3, "smgen", "generate", *args, "--lake", lake)
    assert again.returncode == 0 and "written" in again.stdout, again.stderr
    clean = tmp_path / "clean"
    assert cli(s3, "smgen", "generate", *args, "--lake", clean).returncode == 0
    remote = dataset_files(remote_files(s3, "lake/killed"), "grid-seed7-MEM")
    local = dataset_files(local_files(clean), "grid-seed7-MEM")
    completed, whole = (json.loads(files.pop("grid-seed7-MEM/manifest.json")) for files in (remote, local))
    assert remote == local  # every part, byte for byte
    assert completed["software"].pop("note").endswith("parts were written by an earlier command")
    assert completed == whole  # the same manifest, but for what it says of the parts the killed command wrote
    assert "grid-seed7-MEM/generation.json" not in remote


def test_two_generators_on_one_s3_dataset_commit_once(s3):
    args = ["--setup", "grid", "--mode", "MM", "--transitions", "12000", "--shard-size", "1000", "--seed", "8"]
    lake = "s3://lake/race"
    procs = [
        subprocess.Popen(
            [str(BIN / "smgen"), "generate", *args, "--workers", "1", "--lake", lake],
            env={**os.environ, **s3},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    states = sorted(out.split("\t")[-1].strip() for out, _ in outs)
    assert states == ["exists", "written"]  # exactly one commit; the other found it complete
    check = cli(s3, "smgen", "validate", "grid-seed8-MM", "--lake", lake)
    assert check.returncode == 0, check.stdout


def test_the_commit_is_create_only_on_s3(s3, monkeypatch):
    """Two commits of one dataset: the second finds the first and keeps it (nothing overwritten)."""
    for key, value in s3.items():
        monkeypatch.setenv(key, value)
    from smspace.datagen.generate import commit_dataset, generate, plan_dataset
    from smspace.lake.manifest import GenConfig
    from smspace.lake.store import open_store

    lake = open_store("s3://lake/commit")
    ((manifest, written),) = generate(lake, "grid", ["MEM"], [9], 3000, 1000)
    assert written
    cfg = GenConfig("grid", "MEM", 9, 3000, 1000)
    folder = lake.child(cfg.dataset_id)
    first = folder.read("manifest.json")
    folder.delete("manifest.json")
    plan = plan_dataset(lake, cfg, overwrite=False)
    assert plan.todo == [] and len(plan.found) == 4  # every part found whole and kept
    again, won = commit_dataset(folder, cfg, plan.found)
    assert won and again.shards == manifest.shards
    later, won = commit_dataset(folder, cfg, plan.found)
    assert not won and later.shards == manifest.shards
    assert json.loads(folder.read("manifest.json"))["shards"] == json.loads(first)["shards"]


def test_a_small_arm_dataset_on_s3_equals_local(s3, tmp_path):
    args = ["--setup", "arm", "--mode", "MEM", "--transitions", "256", "--shard-size", "128", "--seed", "1"]
    remote = cli(s3, "smgen", "generate", *args, "--lake", "s3://lake/arm", timeout=600)
    assert remote.returncode == 0, remote.stderr
    local = cli(s3, "smgen", "generate", *args, "--lake", tmp_path / "lake", timeout=600)
    assert local.returncode == 0, local.stderr
    got = dataset_files(remote_files(s3, "lake/arm"), "arm-seed1-MEM")
    assert got == dataset_files(local_files(tmp_path / "lake"), "arm-seed1-MEM") and len(got) == 4
    assert cli(s3, "smgen", "validate", "s3://lake/arm/arm-seed1-MEM").returncode == 0


def _one_line_exit_2(proc: subprocess.CompletedProcess, *words: str) -> None:
    line = failed_in_one_line(proc, code=2, alone=True)
    assert all(word in line for word in words), line


@pytest.mark.parametrize("command", ["ls", "generate"])
def test_bad_storage_is_one_line_and_writes_nothing(s3, command):
    gen = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", "100"]
    args = (lambda lake: ["ls", "--lake", lake]) if command == "ls" else (lambda lake: [*gen, "--lake", lake])
    before = remote_files(s3, "lake")

    _one_line_exit_2(cli(s3, "smgen", *args("foo://bucket/lake")), "unknown storage scheme")
    _one_line_exit_2(cli(s3, "smgen", *args("s3://no-such-bucket/lake")), "no such bucket")
    wrong = s3 | {"AWS_ACCESS_KEY_ID": "AKIAWRONGWRONGWRONG1", "AWS_SECRET_ACCESS_KEY": "wrong"}
    _one_line_exit_2(cli(wrong, "smgen", *args("s3://lake/bad")), "access denied")
    closed = s3 | {"AWS_ENDPOINT_URL": f"http://127.0.0.1:{free_port()}"}
    _one_line_exit_2(cli(closed, "smgen", *args("s3://lake/bad")), "cannot reach")

    assert remote_files(s3, "lake") == before


def test_every_other_command_takes_an_s3_dataset(s3, tmp_path):
    """preview, view --save and smtrain sweep on a lake that lives on S3."""
    lake = "s3://lake/more"
    sweep = cli(
        s3,
        "smtrain",
        "sweep",
        "--setup",
        "grid",
        "--worlds",
        1,
        "--seed",
        5,
        "--modes",
        "MM",
        "--transitions",
        3000,
        "--steps",
        20,
        "--eval-every",
        10,
        "--lake",
        lake,
        "--out",
        tmp_path / "runs",
    )
    assert sweep.returncode == 0, sweep.stderr
    config = json.loads(next((tmp_path / "runs").glob("*/config.json")).read_text())
    assert config["dataset"] == f"{lake}/grid-seed5-MM"
    preview = cli(s3, "smgen", "preview", "grid-seed5-MM", "--lake", lake, "--out", tmp_path / "png", "--frames", 4)
    assert preview.returncode == 0 and any((tmp_path / "png").glob("*.png")), preview.stderr
    view = cli(s3, "smgen", "view", "grid-seed5-MM", "--lake", lake, "--limit", 200, "--save", tmp_path / "v.rrd")
    assert view.returncode == 0 and (tmp_path / "v.rrd").stat().st_size > 0, view.stderr


def test_run_folders_on_s3_are_written_listed_resumed_and_reported(s3, tmp_path):
    lake, runs = "s3://lake/runfolders", "s3://lake/runs"
    assert cli(s3, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    run = f"{runs}/mm"
    fit = cli(s3, "smtrain", "fit", f"{lake}/grid-seed3-MM", "--steps", 40, "--eval-every", 20, "--out", run)
    assert fit.returncode == 0, fit.stderr
    assert fit.stdout.startswith(f"run: {run}\n")
    more = cli(s3, "smtrain", "fit", "--resume", run, "--steps", 60)
    assert more.returncode == 0, more.stderr
    info = cli(s3, "smtrain", "info", run, "--json")
    assert info.returncode == 0 and json.loads(info.stdout)["step"] == 60
    listing = cli(s3, "smtrain", "ls", "--runs", runs, "--json")
    rows = [json.loads(line) for line in listing.stdout.splitlines()]
    assert [(r["run"], r["state"], r["step"]) for r in rows] == [(run, "finished", 60)]
    fs = s3fs_for(s3)
    names = sorted(p.rsplit("/", 1)[-1] for p in fs.find("lake/runs/mm"))
    assert {"config.json", "metrics.parquet", "checkpoint.pt", "status.json", "step-0000060.parquet"} <= set(names)
    assert not any(name.endswith(".partial") or name == ".lock" for name in names)
    report = cli(s3, "smtrain", "report", run, "--out", tmp_path / "report")
    assert report.returncode == 0 and (tmp_path / "report" / "final.csv").exists(), report.stderr
    view = cli(s3, "smtrain", "view", run, "--save", tmp_path / "run.rrd")
    assert view.returncode == 0, view.stderr


def test_a_ray_sweep_writes_its_run_folders_to_s3(s3, tmp_path):
    """Ray workers share nothing but the bucket: datasets and run folders both live on S3."""
    env = s3 | {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    env.pop("RAY_ADDRESS", None)
    args = ["--setup", "grid", "--worlds", 1, "--seed", 4, "--modes", "MEM,MM", "--transitions", 3000, "--steps", 20]
    sweep = cli(
        env,
        "smtrain",
        "sweep",
        *args,
        "--eval-every",
        10,
        "--lake",
        "s3://lake/raysweep",
        "--out",
        "s3://lake/raysweep-runs",
        "--executor",
        "ray",
        "--workers",
        2,
        "--max-ensemble",
        1,
    )
    assert sweep.returncode == 0, sweep.stderr
    listing = cli(s3, "smtrain", "ls", "--runs", "s3://lake/raysweep-runs", "--json")
    rows = [json.loads(line) for line in listing.stdout.splitlines()]
    assert sorted((r["dataset_id"], r["state"], r["step"]) for r in rows) == [
        ("grid-seed4-MEM", "finished", 20),
        ("grid-seed4-MM", "finished", 20),
    ]


def test_a_forged_object_on_s3_is_never_trained_on_and_intact_ones_cost_one_head(s3, tmp_path, monkeypatch):
    """The ETag of a single PUT is the MD5 the manifest records: an intact shard is trusted on one
    metadata request (never downloaded whole to hash it), a forged one of the same size is refused."""
    from smspace.lake import integrity
    from smspace.lake.dataset import Dataset

    from .conftest import SHARD, forged

    lake = "s3://lake/forged"
    assert cli(s3, "smgen", "generate", *GRID, "--mode", "MEM", "--lake", lake).returncode == 0
    for key, value in s3.items():
        monkeypatch.setenv(key, value)

    def no_download(store, name):
        raise AssertionError(f"{store.url}/{name} was downloaded whole to be hashed")

    with monkeypatch.context() as patched:
        patched.setattr(integrity, "sha256_of", no_download)
        ds = Dataset(f"{lake}/grid-seed3-MEM")
        assert len(ds.read_all()) == 6000 and len(ds.regular_sampling()[0]) == 125
    fs = s3fs_for(s3)
    key = "lake/forged/grid-seed3-MEM/" + SHARD
    original = fs.cat_file(key)
    folder = tmp_path / "copy"
    folder.mkdir()
    fs.pipe_file(key, forged(original, folder))
    result = cli(s3, "smtrain", "fit", f"{lake}/grid-seed3-MEM", "--steps", 50, "--out", tmp_path / "run")
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert SHARD in result.stderr and "sha256" in result.stderr and not (tmp_path / "run").exists()
