"""Object storage that fails: a fault proxy of our own (tests/faults.py) on 127.0.0.1 in front of
moto stalls, resets, truncates, corrupts, loses answers and answers 5xx; two processes write one
run folder. Each case failed before this round (issue: faults on the new surfaces)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from functools import partial

import pytest

from tests.conftest import BIN, GRID, failed_in_one_line
from tests.faults import fault_proxy
from tests.servers import moto_s3, s3fs_for

pytestmark = pytest.mark.slow
FAST = {"SMSPACE_S3_CONNECT_TIMEOUT": "1", "SMSPACE_S3_READ_TIMEOUT": "2", "SMSPACE_S3_ATTEMPTS": "2"}


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    with moto_s3(tmp_path_factory.mktemp("moto") / "moto.log") as env:
        yield env


@pytest.fixture()
def proxy(s3):
    with fault_proxy(s3) as (proxy, env):
        proxy.env = env | FAST
        yield proxy


def run(proxy, *args, timeout: float = 300) -> subprocess.CompletedProcess:
    cmd = [str(BIN / str(args[0])), *map(str, args[1:])]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, **proxy.env})


one_line = partial(failed_in_one_line, code=2, alone=True)  # one_line(result, prog)


def test_a_frozen_endpoint_ends_generate_and_fit_in_one_line(proxy, tmp_path):
    """Every PUT sent `Expect: 100-continue` and waited for an answer with no time limit."""
    lake = "s3://lake/frozen"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    proxy.add("stall", method="PUT")
    started = time.monotonic()
    line = one_line(run(proxy, "smgen", "generate", *GRID, "--mode", "MME", "--lake", lake, timeout=120), "smgen")
    assert "did not answer in time" in line and time.monotonic() - started < 60
    proxy.clear()
    proxy.add("stall")
    started = time.monotonic()
    result = run(proxy, "smtrain", "fit", f"{lake}/grid-seed3-MM", "--steps", 50, "--out", tmp_path / "r", timeout=120)
    assert "did not answer in time" in one_line(result, "smtrain") and time.monotonic() - started < 60
    assert not (tmp_path / "r").exists()


def test_sigterm_ends_a_fit_on_a_frozen_endpoint_within_seconds(proxy):
    lake = "s3://lake/frozen-term"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    args = ["fit", f"{lake}/grid-seed3-MM", "--steps", 100000, "--eval-every", 20, "--out", "s3://lake/frozen-term-run"]
    proc = subprocess.Popen(
        [str(BIN / "smtrain"), *map(str, args)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **proxy.env, "SMSPACE_S3_READ_TIMEOUT": "60"},  # a write would wait a minute
    )
    fs = s3fs_for(proxy.env)
    deadline = time.monotonic() + 120
    while not fs.exists("lake/frozen-term-run/checkpoint.pt"):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.2)
        fs.invalidate_cache()
    proxy.add("stall")
    time.sleep(2)  # the run is now stuck in a storage call
    started = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130 and time.monotonic() - started < 15, stderr
    assert stderr.strip().splitlines()[-1].startswith("interrupted;") and "--resume s3://lake/frozen-term-run" in stderr


def test_a_lost_answer_to_the_manifest_put_still_commits_as_written(proxy):
    """The PUT landed, its answer was lost, the client's retry got 412: it said "exists" and left
    generation.json behind."""
    lake = "s3://lake/lost"
    proxy.add("lose", method="PUT", path="manifest.json", count=1)
    result = run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("\twritten"), result.stdout
    assert [f for _, f in [(m, r) for m, p, r in proxy.seen if "manifest.json" in p and m == "PUT"]][:1] == ["lose"]
    fs = s3fs_for(proxy.env)
    assert not fs.exists("lake/lost/grid-seed3-MM/generation.json")
    assert run(proxy, "smgen", "validate", "grid-seed3-MM", "--lake", lake).returncode == 0


def test_damaged_transfers_are_retried_and_never_called_a_corrupt_shard(proxy, tmp_path):
    """A truncated or corrupted answer is the connection's fault: the read is tried again, and the
    data are exactly the stored ones."""
    lake = "s3://lake/flaky"
    proxy.env |= {"SMSPACE_S3_ATTEMPTS": "4"}  # three failures in a row (503, 503, reset) are still retried
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MEM", "--lake", lake).returncode == 0
    clean = run(
        proxy, "smgen", "export", "grid-seed3-MEM", "--lake", lake, "--format", "parquet", "--out", tmp_path / "a"
    )
    assert clean.returncode == 0, clean.stderr
    for fault in ("corrupt", "truncate", "503", "reset"):
        proxy.add(fault, method="GET", path="shard-", count=2)
    out = tmp_path / "b.parquet"
    flaky = run(proxy, "smgen", "export", "grid-seed3-MEM", "--lake", lake, "--format", "parquet", "--out", out)
    assert flaky.returncode == 0, flaky.stderr
    assert sum(1 for _, _, f in proxy.seen if f != "pass") == 8  # every fault was met
    import pyarrow.parquet as pq

    assert pq.read_table(out).equals(pq.read_table(tmp_path / "a"))
    proxy.clear()
    fs = s3fs_for(proxy.env)  # now the stored bytes themselves: a flipped byte inside a chunk
    key = "lake/flaky/grid-seed3-MEM/shard-00001.mcap"
    data = bytearray(fs.cat_file(key))
    data[len(data) // 3] ^= 0x5A
    fs.pipe_file(key, bytes(data))
    result = run(proxy, "smgen", "validate", "grid-seed3-MEM", "--lake", lake)
    assert result.returncode == 1 and "shard-00001.mcap" in result.stdout


def test_two_finalizes_at_once_one_commits_the_other_finds_it(proxy, tmp_path):
    """The loser of the race got 412 and then read its stale listing: "is not a dataset"."""
    lake = "s3://lake/final"
    for rank in (0, 1):
        args = ["generate", *GRID, "--mode", "MM", "--rank", rank, "--world-size", 2, "--lake", lake]
        assert run(proxy, "smgen", *args).returncode == 0
    procs = [
        subprocess.Popen(
            [str(BIN / "smgen"), "finalize", "grid-seed3-MM", "--lake", lake],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **proxy.env},
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    states = sorted(out.strip().rsplit("\t", 1)[-1] for out, _ in outs)
    assert states in (["exists", "written"], ["written", "written"]), outs  # written twice: identical bytes raced


def test_a_finalize_that_meets_a_stale_listing_reads_the_committed_manifest(s3, monkeypatch):
    for key, value in s3.items():
        monkeypatch.setenv(key, value)
    from smspace.datagen.generate import Share, finalize, generate
    from smspace.lake.store import open_store

    lake = open_store("s3://lake/stale")
    for rank in (0, 1):
        generate(lake, "grid", ["MM"], [3], 6000, 2500, share=Share(rank, 2))
    folder = lake.child("grid-seed3-MM")
    folder.fs.ls(folder.root, refresh=True)  # the listing this process holds: no manifest yet
    other = subprocess.run(
        [str(BIN / "smgen"), "finalize", "grid-seed3-MM", "--lake", "s3://lake/stale"],
        capture_output=True,
        text=True,
        env={**os.environ, **s3},
    )
    assert other.returncode == 0 and other.stdout.strip().endswith("\twritten")
    ((manifest, written),) = finalize(lake, [folder])
    assert manifest.dataset_id == "grid-seed3-MM" and not written


def test_two_fits_into_one_s3_run_folder_never_mix(proxy, tmp_path):
    """Two fits with other learning rates into one --out: both exited 0 and config, metrics and
    checkpoint came from different runs. Now the first to lose a write stops in one line."""
    lake, out = "s3://lake/twofits", "s3://lake/twofits-run"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    args = ["fit", f"{lake}/grid-seed3-MM", "--steps", 100000, "--eval-every", 10, "--out", out]
    first = subprocess.Popen(
        [str(BIN / "smtrain"), *map(str, args), "--lr-start", "0.001"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **proxy.env},
    )
    fs = s3fs_for(proxy.env)
    deadline = time.monotonic() + 120
    while not fs.exists(f"{out[5:]}/checkpoint.pt"):
        assert first.poll() is None and time.monotonic() < deadline, first.communicate()
        time.sleep(0.2)
        fs.invalidate_cache()
    refused = run(proxy, "smtrain", *args[:-2], "--out", out, "--steps", 100, "--lr-start", "0.002")
    assert "already holds a run" in one_line(refused, "smtrain")
    second = run(proxy, "smtrain", *args[:-6], "--steps", 40, "--eval-every", 10, "--lr-start", "0.002",
                 "--out", out, "--overwrite")  # fmt: skip
    assert second.returncode == 0, second.stderr
    _, stderr = first.communicate(timeout=120)
    assert first.returncode == 2 and "another process writes this run folder" in stderr, stderr
    assert stderr.count("smtrain: error") == 1
    config = json.loads(fs.cat_file(f"{out[5:]}/config.json"))
    assert config["lr_start"] == 0.002 and config["steps"] == 40
    status = json.loads(fs.cat_file(f"{out[5:]}/status.json"))
    assert status["state"] == "finished" and status["run_id"] == config["run_id"]
    resumed = run(proxy, "smtrain", "fit", "--resume", out, "--steps", 60)
    assert resumed.returncode == 0, resumed.stderr


def test_resume_refuses_a_folder_holding_parts_of_two_runs(s3, tmp_path, monkeypatch):
    for key, value in s3.items():
        monkeypatch.setenv(key, value)
    from click.testing import CliRunner

    from smspace.cli import smtrain as main

    lake, out = "s3://lake/mixed", "s3://lake/mixed-run"
    assert (
        subprocess.run(
            [str(BIN / "smgen"), "generate", *GRID, "--mode", "MM", "--lake", lake], env={**os.environ, **s3}
        ).returncode
        == 0
    )
    for seed in (1, 2):
        args = [
            "fit",
            f"{lake}/grid-seed3-MM",
            "--steps",
            20,
            "--eval-every",
            10,
            "--seed",
            seed,
            "--out",
            f"{out}-{seed}",
        ]
        assert CliRunner().invoke(main, args).exit_code == 0
    fs = s3fs_for(s3)
    fs.pipe_file(f"{out[5:]}-1/checkpoint.pt", fs.cat_file(f"{out[5:]}-2/checkpoint.pt"))  # run 2's checkpoint in run 1
    result = CliRunner().invoke(main, ["fit", "--resume", f"{out}-1", "--steps", 40])
    assert result.exit_code == 2 and "holds parts of different runs" in result.output, result.output
    assert json.loads(fs.cat_file(f"{out[5:]}-1/config.json"))["steps"] == 20  # nothing written


@pytest.mark.parametrize("fault", ["corrupt", "truncate", "503", "stall"])
def test_a_transient_read_of_a_manifest_is_never_called_another_config(proxy, fault):
    """One garbled, cut, refused or stalled GET of manifest.json: generate said "was generated with
    another config; pass --overwrite", advice that deletes a sound dataset. Only a manifest read
    whole and parsed is compared: the same command finds the dataset complete."""
    lake = f"s3://lake/transient-{fault}"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    proxy.add(fault, method="GET", path="grid-seed3-MM/manifest.json", count=1)
    again = run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake)
    assert again.returncode == 0 and again.stdout.strip().endswith("\texists"), again.stderr
    assert "another config" not in again.stderr
    assert any(f == fault for _, p, f in proxy.seen if "manifest.json" in p), proxy.seen  # the fault was met


@pytest.mark.parametrize("fault", ["truncate", "corrupt"])
def test_a_whole_read_damaged_in_transit_is_read_again_not_called_damaged(proxy, fault):
    """validate read each file whole once: one cut or garbled answer was "18166 bytes, manifest says
    36333 (truncated or replaced)" or "sha256 differs", and a garbled manifest "corrupt manifest …
    can't decode byte". Now a read that does not match is read again; only the same wrong bytes
    twice are a damaged file, and answers that differ every time are said to be the transfer's."""
    lake = f"s3://lake/whole-{fault}"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    proxy.add(fault, method="GET", path="grid-seed3-MM/shard-00001", count=1)
    proxy.add(fault, method="GET", path="grid-seed3-MM/manifest.json", count=1)
    once = run(proxy, "smgen", "validate", "grid-seed3-MM", "--lake", lake)
    assert once.returncode == 0, once.stdout + once.stderr
    assert sum(f == fault for _, _, f in proxy.seen) == 2  # both faults were met
    proxy.clear()
    proxy.add(fault, method="GET", path="grid-seed3-MM/shard-00001")  # every read damaged, differently
    always = run(proxy, "smgen", "validate", "grid-seed3-MM", "--lake", lake)
    text = always.stdout + always.stderr
    assert always.returncode == 1 and "shard-00001.mcap" in text, text
    # the object's ETag is the recorded MD5: the storage holds it intact, so the reads are to blame
    assert "transfer" in text and "differs" not in text and "truncated or replaced" not in text, text


@pytest.mark.parametrize("fault", ["reset", "truncate", "corrupt"])
def test_a_shard_read_failing_once_in_transit_does_not_stop_a_fit(proxy, tmp_path, fault):
    """One connection reset mid-GET of a shard during fit was "corrupt shard …: ClientPayloadError:
    Response payload is not completed"."""
    lake = f"s3://lake/fit-{fault}"
    assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    proxy.add(fault, method="GET", path="grid-seed3-MM/shard-00000", count=1)
    out = tmp_path / "run"
    result = run(proxy, "smtrain", "fit", f"{lake}/grid-seed3-MM", "--steps", 20, "--eval-every", 10, "--out", out)
    assert result.returncode == 0, result.stderr
    assert any(f == fault for _, _, f in proxy.seen), proxy.seen


def frozen_part_way(proxy, after: int, *args) -> tuple[str, list[tuple[str, str]]]:
    """The command run with the endpoint frozen from its `after`-th request on: its one line, and
    the requests that met the freeze."""
    proxy.clear()
    proxy.seen.clear()
    proxy.add("stall", after=after)
    line = one_line(run(proxy, *args, timeout=120), str(args[0]))
    return line, [(m, p) for m, p, f in proxy.seen if f == "stall"]


@pytest.mark.parametrize("after", [1, 4, 7, 10])
def test_a_freeze_part_way_through_generate_ends_it_at_the_first_unanswered_request(proxy, after):
    """Timed-out LISTs and HEADs were retried, then taken for "absent" (a part to redo) and passed
    over; the command failed only at its next PUT, 71-145 s where the promised bound was 30 s. Now
    the first request the endpoint leaves unanswered, after its attempts, ends the command: counted
    in requests, not seconds, so the test holds on a busy machine."""
    lake = "s3://lake/freeze"
    args = ["smgen", "generate", "--setup", "grid", "--transitions", 6000, "--shard-size", 2500, "--mode", "MME"]
    line, stalled = frozen_part_way(proxy, after, *args, "--seed", 10 + after, "--lake", lake)
    assert "did not answer in time" in line, line
    assert len(stalled) == int(FAST["SMSPACE_S3_ATTEMPTS"]) and len(set(stalled)) == 1, stalled


@pytest.mark.parametrize("after", [1, 3, 6])
def test_a_freeze_part_way_through_reading_commands_ends_them_at_the_first_unanswered_request(proxy, tmp_path, after):
    lake = "s3://lake/freeze-read"
    if after == 1:
        assert run(proxy, "smgen", "generate", *GRID, "--mode", "MM", "--lake", lake).returncode == 0
    for args in (
        ["smgen", "ls", "--lake", lake],
        ["smgen", "validate", "grid-seed3-MM", "--lake", lake],
        ["smtrain", "fit", f"{lake}/grid-seed3-MM", "--steps", 20, "--out", tmp_path / f"r{after}"],
    ):
        line, stalled = frozen_part_way(proxy, after, *args)
        assert "did not answer in time" in line, (args, line)
        assert len(stalled) == int(FAST["SMSPACE_S3_ATTEMPTS"]) and len(set(stalled)) == 1, (args, stalled)
