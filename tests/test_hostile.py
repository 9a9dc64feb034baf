"""Hostile files and kills: every failure is one clear line naming the file, nothing is left
half-done, and leftovers of killed writers never block the next command."""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from smspace.train.run_dir import RunDir, RunView

from .conftest import BIN, SAMPLES, smgen, smtrain
from .servers import alive, children_of


@pytest.fixture
def samples_copy(tmp_path) -> Path:
    dst = tmp_path / "lake"
    shutil.copytree(SAMPLES, dst)
    return dst


def flip(path: Path, rng: np.random.Generator) -> int:
    """Replace one byte at a random offset with another value; the size stays."""
    data = bytearray(path.read_bytes())
    at = int(rng.integers(len(data)))
    data[at] ^= int(rng.integers(1, 256))
    path.write_bytes(bytes(data))
    return at


def assert_one_line_naming(result, name: str, prog: str) -> None:
    """The reader refused the damaged file (a reader that succeeded on it fails this), in one line."""
    assert "Traceback" not in result.output, result.output
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"escaped: {result.exception!r}")
    assert result.exit_code != 0, f"read a damaged {name} without a word: {result.output}"
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: ") and name in lines[0], result.output


@pytest.mark.parametrize("dataset", ["grid-seed0-MEM", "arm-seed0-MME"])
def test_random_byte_flips_are_named_by_validate(samples_copy, dataset):
    """60 seeded single-byte flips per setup: validate reports each with lines naming the shard, exit 1."""
    rng = np.random.default_rng(np.random.SeedSequence(2026, spawn_key=(len(dataset),)))
    folder = samples_copy / dataset
    shards = sorted(folder.glob("shard-*.mcap"))
    originals = {p: p.read_bytes() for p in shards}
    for _ in range(60):
        shard = shards[int(rng.integers(len(shards)))]
        at = flip(shard, rng)
        result = smgen("validate", "--lake", samples_copy, dataset)
        assert result.exception is None or isinstance(result.exception, SystemExit), (at, result.exception)
        assert result.exit_code == 1, (at, result.output)
        lines = result.output.strip().splitlines()
        assert lines and all(line.startswith(f"{dataset}/{shard.name}: ") for line in lines), (at, result.output)
        shard.write_bytes(originals[shard])
    assert smgen("validate", "--lake", samples_copy, dataset).exit_code == 0


def test_random_byte_flips_give_readers_one_line(samples_copy, tmp_path):
    """export, view, preview and info meet flipped shards: one line naming the shard, never a traceback."""
    rng = np.random.default_rng(7)
    for dataset in ("grid-seed0-MM", "arm-seed0-MEM"):
        shards = sorted((samples_copy / dataset).glob("shard-*.mcap"))
        originals = {p: p.read_bytes() for p in shards}
        for k in range(10):
            shard = shards[0]  # the first shard: every reader below reads it
            flip(shard, rng)
            out = tmp_path / f"{dataset}-{k}"
            for args in (
                ["export", dataset, "--format", "parquet", "--out", out / "x.parquet"],
                ["view", dataset, "--save", out / "x.rrd"],
                ["preview", dataset, "--out", out / "preview"],
            ):
                assert_one_line_naming(smgen(*args, "--lake", samples_copy), shard.name, "smgen")
            shard.write_bytes(originals[shard])


def test_fit_on_a_flipped_shard_is_refused_in_one_line_before_anything_is_written(samples_copy, tmp_path):
    """Every flip is seen (the shard's sha256 is checked before training), even one in a field the
    reader never decodes, and no run folder is created."""
    rng = np.random.default_rng(11)
    shard = samples_copy / "grid-seed0-MME" / "shard-00001.mcap"  # evaluation reads shard 0 only
    original = shard.read_bytes()
    for k in range(6):
        flip(shard, rng)
        out = tmp_path / f"run{k}"
        args = ["fit", "grid-seed0-MME", "--lake", samples_copy, "--out", out, "--steps", 60, "--eval-every", 20]
        result = smtrain(*args)
        assert_one_line_naming(result, shard.name, "smtrain")
        assert result.exit_code == 2 and not out.exists()
        shard.write_bytes(original)


def test_leftovers_of_killed_writers_never_block_a_resume(tmp_path):
    out = tmp_path / "run"
    args = ["fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--eval-every", 10]
    assert smtrain(*args, "--steps", 20).exit_code == 0
    leftovers = [
        out / "embeddings" / "step-0000030.parquet.4242.partial",
        out / "embeddings" / "s_t1_pred-0000030.npy.4242.partial",
        out / "checkpoint.pt.4242.partial",
        out / "metrics.parquet.17.partial",
    ]
    for path in leftovers:
        path.write_bytes(b"half written")
    resumed = smtrain("fit", "--resume", out, "--steps", 40)
    assert resumed.exit_code == 0, resumed.output
    assert not any(p.exists() for p in leftovers)
    assert [r["step"] for r in RunView.open(out).metrics()] == [0, 10, 20, 30, 40]


def test_a_checkpoint_holding_objects_is_refused_in_one_line(tmp_path):
    out = tmp_path / "run"
    assert (
        smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 10, "--eval-every", 10).exit_code
        == 0
    )
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    ckpt["payload"] = Path("/etc/passwd")  # any object outside tensors and plain data
    torch.save(ckpt, out / "checkpoint.pt")
    result = smtrain("fit", "--resume", out, "--steps", 20)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "not a smspace checkpoint" in lines[0] and "not loaded" in lines[0]
    assert "weights_only" not in result.output


# -- numeric options the formats cannot hold are refused before anything is written -------------
def test_a_seed_beyond_int64_is_refused_and_the_lake_stays_usable(tmp_path):
    lake = tmp_path / "lake"
    for args in (["--seed", 2**63], ["--seed", 2**63 - 1, "--worlds", 2]):
        result = smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 100, *args, "--lake", lake)
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and "seed" in lines[0], result.output
        assert not lake.exists()
    top = 2**63 - 1
    args = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", 100, "--seed", top, "--lake", lake]
    assert smgen(*args).exit_code == 0
    assert smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 100, "--lake", lake).exit_code == 0
    listed = smgen("ls", "--lake", lake, "--json").output.splitlines()
    assert len(listed) == 2 and any(f"seed{top}" in line for line in listed)


# -- what a resume keeps is verified -----------------------------------------------------------------
def test_a_resumed_generation_redoes_a_shard_damaged_meanwhile(tmp_path):
    lake = tmp_path / "lake"
    args = ["generate", "--setup", "grid", "--mode", "MEM", "--transitions", 5000, "--shard-size", 1000]
    assert smgen(*args, "--lake", tmp_path / "clean").exit_code == 0
    assert smgen(*args, "--lake", lake).exit_code == 0
    folder = lake / "grid-seed0-MEM"
    (folder / "manifest.json").unlink()  # as if the generation had not finished
    (folder / "generation.json").write_text(
        (tmp_path / "clean" / "grid-seed0-MEM" / "manifest.json").read_text()  # any JSON with the right hash
    )
    rng = np.random.default_rng(3)
    for name in ("shard-00001.mcap", "shard-00003.mcap"):
        flip(folder / name, rng)
    assert smgen(*args, "--lake", lake).exit_code == 0
    for shard in sorted((tmp_path / "clean" / "grid-seed0-MEM").glob("shard-*")):
        assert (folder / shard.name).read_bytes() == shard.read_bytes(), shard.name
    assert smgen("validate", "--lake", lake, "grid-seed0-MEM").exit_code == 0


def test_fit_resume_refuses_a_regenerated_dataset(tmp_path):
    lake, out = tmp_path / "lake", tmp_path / "run"
    gen = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", 3000, "--lake", lake]
    assert smgen(*gen).exit_code == 0
    assert (
        smtrain("fit", "grid-seed0-MM", "--lake", lake, "--out", out, "--steps", 20, "--eval-every", 10).exit_code == 0
    )
    assert smgen(*gen[:-2], "--shard-size", 1000, "--lake", lake, "--overwrite").exit_code == 0  # same id, new bytes
    result = smtrain("fit", "--resume", out, "--steps", 40)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and "is not the one" in lines[0], result.output
    assert RunView.open(out).checkpoint_step() == 20


# -- a manifest names nothing outside its folder and every field is checked ---------------------------
def _edit_manifest(folder: Path, edit) -> None:
    import json

    raw = json.loads((folder / "manifest.json").read_text())
    edit(raw)
    (folder / "manifest.json").write_text(json.dumps(raw))


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda m: m["shards"][0].update(file="/etc/passwd"), "file name"),
        (lambda m: m["shards"][0].update(file="../grid-seed0-MM/shard-00000.mcap"), "file name"),
        (lambda m: m["regular_sampling"].update(file="/dev/zero"), "file name"),
        (lambda m: m["normalisation"]["m_min"].__setitem__(0, float("nan")), "finite"),
        (
            lambda m: m["normalisation"].update(s_min=m["normalisation"]["s_max"], s_max=m["normalisation"]["s_min"]),
            "exceeds",
        ),
        (lambda m: m.update(mode="MXM"), "mode"),
        (lambda m: m.update(config_hash="0" * 16), "config_hash"),
        (lambda m: m.update(dataset_id="grid-seed9-MEM"), "dataset_id"),
        (lambda m: m.update(transitions="4096"), "transitions"),
        (lambda m: m.update(shards={"file": "x"}), "shards"),
        (lambda m: m.update(n_motor=[3]), "n_motor"),
        (lambda m: m.pop("normalisation"), "normalisation"),
        (lambda m: [shard.update(bytes=2**62) for shard in m["shards"]], "bytes"),  # their sum passes int64
        (lambda m: m["config"].update(transitions=2**40, shard_size=2**40, batch_size=1), "shard_size"),
        (lambda m: m["regular_sampling"].update(count=2**40), "regular_sampling count"),
        (lambda m: m.update(sensor_shape=[65536, 65536, 3]), "sensor_shape"),
    ],
)
def test_hostile_manifests_are_named_in_one_line_everywhere(samples_copy, tmp_path, edit, needle):
    folder = samples_copy / "grid-seed0-MEM"
    _edit_manifest(folder, edit)
    result = smgen("validate", "--lake", samples_copy, "grid-seed0-MEM")
    lines = result.output.strip().splitlines()
    assert result.exit_code == 1 and len(lines) == 1 and needle in lines[0] and "manifest" in lines[0], result.output
    for args in (
        ["info", "grid-seed0-MEM"],
        ["export", "grid-seed0-MEM", "--format", "parquet", "--out", tmp_path / "x"],
    ):
        out = smgen(*args, "--lake", samples_copy)
        assert out.exit_code == 2 and len(out.output.strip().splitlines()) == 1 and needle in out.output, out.output
    out = smtrain("fit", "grid-seed0-MEM", "--lake", samples_copy, "--out", tmp_path / "run", "--steps", 10)
    assert out.exit_code == 2 and needle in out.output and not (tmp_path / "run").exists()


def test_links_and_special_files_in_a_dataset_are_refused_without_blocking(samples_copy):
    import os

    folder = samples_copy / "grid-seed0-MM"
    (folder / "shard-00001.mcap").unlink()
    os.mkfifo(folder / "shard-00001.mcap")  # reading a FIFO would block forever
    (folder / "regular.mcap").unlink()
    (folder / "regular.mcap").symlink_to(SAMPLES / "grid-seed0-MM" / "regular.mcap")
    result = smgen("validate", "--lake", samples_copy, "grid-seed0-MM")
    assert result.exit_code == 1
    assert "grid-seed0-MM/shard-00001.mcap: " in result.output and "regular file" in result.output
    assert "grid-seed0-MM/regular.mcap: " in result.output


def test_a_folder_holding_only_a_manifest_does_not_validate(samples_copy):
    folder = samples_copy / "grid-seed0-MME"
    for path in folder.glob("*.mcap"):
        path.unlink()
    result = smgen("validate", "--lake", samples_copy, "grid-seed0-MME")
    assert result.exit_code == 1 and result.output.count("missing") == 3


# -- listing survives one bad entry ------------------------------------------------------------------
def test_smtrain_ls_lists_around_broken_runs_and_shows_dead_runs_as_stale(tmp_path):
    import json
    import os

    runs = tmp_path / "runs"
    for name in ("good", "bad-config", "bad-status", "bad-metrics", "dead", "caf\udce9"):
        out = runs / name
        args = ["fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 10, "--eval-every", 10]
        assert smtrain(*args).exit_code == 0
    (runs / "bad-config" / "config.json").write_text("{not json")
    (runs / "bad-status" / "status.json").write_bytes(b"\xff\xfe")
    (runs / "bad-metrics" / "metrics.parquet").write_bytes(b"PAR1 nonsense")
    dead = {"state": "running", "step": 10, "message": "", "pid": 2**22 + 12345, "host": os.uname().nodename}
    (runs / "dead" / "status.json").write_text(json.dumps(dead))
    result = smtrain("ls", "--runs", runs)
    assert result.exit_code == 0, result.output
    states = {line.split()[0]: line.split()[1] for line in result.output.splitlines()[1:]}
    assert states == {
        "good": "finished",
        "bad-config": "broken",
        "bad-status": "broken",
        "bad-metrics": "broken",
        "dead": "stale",
        "caf\ufffd": "finished",
    }
    assert len(smtrain("ls", "--runs", runs, "--json").output.splitlines()) == 6


def test_a_corrupt_catalog_is_rebuilt_from_the_manifests(samples_copy):
    (samples_copy / "catalog.parquet").write_bytes(b"garbage")
    result = smgen("ls", "--lake", samples_copy, "--json")
    assert result.exit_code == 0 and len(result.output.splitlines()) == 6
    _edit_manifest(samples_copy / "grid-seed0-MM", lambda m: m.update(config_hash="x"))
    (samples_copy / "catalog.parquet").write_bytes(b"garbage")
    listed = smgen("ls", "--lake", samples_copy, "--json")  # the broken one left out, and said so
    assert len(listed.stdout.splitlines()) == 5 and "left out" in listed.stderr, listed.output


# -- output files: never overwritten without --overwrite, never onto an input, always whole ----------
def test_export_refuses_to_overwrite_and_never_writes_onto_its_input(samples_copy, tmp_path):
    shard = samples_copy / "grid-seed0-MM" / "shard-00000.mcap"
    before = shard.read_bytes()
    for overwrite in ([], ["--overwrite"]):
        args = ["export", "grid-seed0-MM", "--lake", samples_copy, "--format", "parquet", "--out", shard, *overwrite]
        result = smgen(*args)
        assert result.exit_code == 2 and "inside" in result.output, result.output
    assert shard.read_bytes() == before
    out = tmp_path / "x.parquet"
    out.write_bytes(b"precious")
    args = ["export", "grid-seed0-MM", "--lake", samples_copy, "--format", "parquet", "--out", out]
    result = smgen(*args)
    assert result.exit_code == 2 and "--overwrite" in result.output and out.read_bytes() == b"precious"
    assert smgen(*args, "--overwrite").exit_code == 0 and out.read_bytes() != b"precious"
    assert not list(tmp_path.glob("*.partial"))


def test_view_save_is_atomic_and_refuses_to_overwrite(samples_copy, tmp_path, monkeypatch):
    out = tmp_path / "x.rrd"
    args = ["view", "grid-seed0-MM", "--lake", samples_copy, "--save", out]
    assert smgen(*args).exit_code == 0
    first = out.read_bytes()
    result = smgen(*args)
    assert result.exit_code == 2 and "--overwrite" in result.output and out.read_bytes() == first

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")

    import smspace.datagen.view as dataset_view

    monkeypatch.setattr(dataset_view, "_series", full_disk)  # fails midway through logging
    result = smgen(*args, "--overwrite")
    assert result.exit_code != 0
    assert out.read_bytes() == first and not list(tmp_path.glob("*.partial"))
    inside = smgen("view", "grid-seed0-MM", "--lake", samples_copy, "--save", samples_copy / "grid-seed0-MM" / "a.rrd")
    assert inside.exit_code == 2 and "inside" in inside.output


# -- concurrent writers -----------------------------------------------------------------------------
def test_two_identical_generations_at_once_both_succeed_with_one_dataset(tmp_path):
    import subprocess

    from .conftest import run_cmd

    lake = tmp_path / "lake"
    args = ["generate", "--setup", "grid", "--mode", "all", "--transitions", 60000, "--shard-size", 5000]
    cmd = [str(BIN / "smgen"), *map(str, args), "--workers", "1", "--lake", str(lake)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    words = sorted(line.split("\t")[2] for out, _ in outs for line in out.splitlines())
    assert words == ["exists"] * 3 + ["written"] * 3
    assert (
        run_cmd("smgen", "validate", "--lake", lake, "grid-seed0-MEM", "grid-seed0-MM", "grid-seed0-MME").returncode
        == 0
    )


def test_a_run_folder_being_trained_refuses_a_second_trainer(tmp_path):
    import json
    import os
    import signal
    import subprocess
    import time

    out = tmp_path / "run"
    cmd = [str(BIN / "smtrain"), "fit", "grid-seed0-MM", "--lake", str(SAMPLES), "--out", str(out)]
    proc = subprocess.Popen([*cmd, "--steps", "100000", "--eval-every", "50"], stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 600  # a busy machine may take a minute to start it: wait, never go on without it
        while not (out / "status.json").exists():
            assert proc.poll() is None and time.time() < deadline, "the first trainer never began its run"
            time.sleep(0.05)
        for extra in (["--overwrite"], []):
            args = ["fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 10, *extra]
            result = smtrain(*args) if extra else smtrain("fit", "--resume", out)
            lines = result.output.strip().splitlines()
            assert result.exit_code == 2 and len(lines) == 1 and "being trained by another process" in lines[0]
        assert json.loads((out / "status.json").read_text())["state"] == "running"
        assert RunView.open(out).config.steps == 100000
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert RunView.open(out).status().state == "stale"
    taker = RunDir.open(out)
    taker.claim()  # the lock died with its holder: another process may train the run now
    taker.release()


# -- extreme options: bounded before anything is allocated or written -----------------------------
@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        (["--threads", 100000], "--threads"),
        (["--lr-start", "nan"], "--lr-start"),
        (["--lr-end", "-1e-3"], "--lr-end"),
        (["--lr-start", "inf"], "--lr-start"),
        (["--nh", 10**7], "--nh"),
        (["--encoder-layers", "100,100000000"], "--encoder-layers"),
        (["--predictor-layers", ",".join(["8"] * 40)], "--predictor-layers"),
        (["--loader-workers", 300], "--loader-workers"),
        (["--batch-size", 10**8], "--batch-size"),
        (["--batch-size", 5000], "larger than the dataset"),
        (["--nh", 60000, "--encoder-layers", "60000,60000,60000"], "GiB of memory"),
    ],
)
def test_extreme_training_options_get_one_line_and_exit_2(tmp_path, flags, needle):
    out = tmp_path / "run"
    result = smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, *flags)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and needle in lines[0], result.output
    assert not out.exists()


def test_extreme_generation_options_get_one_line_and_write_nothing(tmp_path):
    lake = tmp_path / "lake"
    for transitions, needle in ((10**13, "more than a dataset may hold"), (10**11, "MiB free")):
        result = smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", transitions, "--lake", lake)
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and needle in lines[0], result.output
        assert not lake.exists() or not any(lake.iterdir())


def test_the_disk_estimate_counts_only_missing_shards(tmp_path, monkeypatch):
    import shutil as sh

    import smspace.lake.store as lake_store

    lake = tmp_path / "lake"
    args = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", 200000, "--shard-size", 50000]
    assert smgen(*args, "--lake", lake).exit_code == 0
    (lake / "grid-seed0-MM" / "shard-00002.mcap").unlink()  # needs ~1 MiB of a 3.2 MB dataset
    real = sh.disk_usage(lake)
    monkeypatch.setattr(lake_store.shutil, "disk_usage", lambda p: real._replace(free=3 << 20))
    assert smgen(*args, "--lake", lake).exit_code == 0  # 3 MiB free is enough for one shard
    (lake / "grid-seed0-MM" / "shard-00002.mcap").unlink()
    monkeypatch.setattr(lake_store.shutil, "disk_usage", lambda p: real._replace(free=1 << 19))
    result = smgen(*args, "--lake", lake)
    assert result.exit_code == 2 and "MiB free" in result.output


# -- no process outlives the command that started it ------------------------------------------------
def _wait_gone(pids: set[int], seconds: float = 15) -> list[int]:
    import time

    deadline = time.time() + seconds
    while time.time() < deadline and alive(pids):
        time.sleep(0.1)
    return alive(pids)


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_generation_workers_die_with_their_parent(tmp_path, sig):
    import signal
    import subprocess
    import time

    import psutil

    cmd = [str(BIN / "smgen"), "generate", "--setup", "grid", "--mode", "all", "--transitions", "3000000"]
    cmd += ["--shard-size", "20000", "--workers", "2", "--lake", str(tmp_path / "lake")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline, workers = time.time() + 60, set()
        while time.time() < deadline and len(workers) < 3:  # two workers and the resource tracker
            workers = {p.pid for p in psutil.Process(proc.pid).children(recursive=True)}
            time.sleep(0.1)
        assert len(workers) >= 2, workers
        proc.send_signal(getattr(signal, sig))
        proc.wait(timeout=30)
        assert not _wait_gone(workers), "workers outlived their parent"
        if sig == "SIGTERM":
            assert proc.returncode == 130 and "interrupted" in proc.stderr.read().decode()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_the_web_viewer_dies_with_its_parent(sig):
    import signal
    import subprocess
    import time

    import psutil

    from tests.servers import free_port

    def listening(port: int) -> bool:
        return any(c.status == "LISTEN" and c.laddr.port == port for c in psutil.net_connections("tcp"))

    web, grpc = free_port(), free_port()
    cmd = [str(BIN / "smgen"), "view", "grid-seed0-MM", "--lake", str(SAMPLES), "--limit", "500", "--web"]
    cmd += ["--web-port", str(web), "--grpc-port", str(grpc)]
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    viewers: set[int] = set()
    try:
        deadline = time.time() + 300
        while time.time() < deadline and not listening(web):
            time.sleep(0.2)
        assert listening(web)
        viewers = children_of(proc.pid)
        assert viewers
        proc.send_signal(getattr(signal, sig))
        proc.wait(timeout=30)
        assert not _wait_gone(viewers), "the viewer outlived smgen"
        deadline = time.time() + 10
        while time.time() < deadline and (listening(web) or listening(grpc)):
            time.sleep(0.2)
        assert not listening(web) and not listening(grpc)
    finally:
        for pid in [proc.pid, *viewers]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def test_world_counts_and_shard_sizes_are_bounded(tmp_path):
    lake = tmp_path / "lake"
    for flags, needle in ((["--worlds", 10**9], "--worlds"), (["--shard-size", 10**9], "--shard-size")):
        result = smgen("generate", "--setup", "grid", "--mode", "MM", *flags, "--lake", lake)
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and needle in lines[0], result.output
    result = smtrain("sweep", "--setup", "grid", "--worlds", 10**9, "--lake", lake, "--out", tmp_path / "runs")
    assert result.exit_code == 2 and "--worlds" in result.output
    assert not lake.exists() or not any(lake.iterdir())


def test_a_manifest_with_huge_sizes_leaves_the_lake_usable(samples_copy):
    """Two shards of 2**62 bytes: their sum overflowed the catalog (OverflowError in every `ls` and
    every later `generate` into that lake)."""
    _edit_manifest(samples_copy / "grid-seed0-MEM", lambda m: [s.update(bytes=2**62) for s in m["shards"]])
    (samples_copy / "catalog.parquet").unlink()
    listed = smgen("ls", "--lake", samples_copy, "--json")
    assert listed.exit_code == 0, listed.output
    assert len(listed.stdout.splitlines()) == 5  # the five sound datasets; the broken one is left out
    assert "1 dataset folder(s) left out, their manifest does not read: grid-seed0-MEM" in listed.stderr
    made = smgen(
        "generate", "--setup", "grid", "--mode", "MM", "--seed", 4, "--transitions", 1000, "--lake", samples_copy
    )
    assert made.exit_code == 0, made.output


def test_finalize_of_a_hostile_generation_record_is_one_line(tmp_path):
    import json

    lake = tmp_path / "lake"
    args = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", 3000, "--shard-size", 1000]
    assert smgen(*args, "--rank", 0, "--world-size", 2, "--lake", lake).exit_code == 0
    record = lake / "grid-seed0-MM" / "generation.json"
    raw = json.loads(record.read_text())
    raw["config"].update(transitions=2**40, shard_size=2**18, batch_size=1)  # 2**22 shards
    record.write_text(json.dumps(raw))
    result = smgen("finalize", "grid-seed0-MM", "--lake", lake)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and "shards, more than" in lines[0], result.output
