"""One run on two processes (DDP, gloo, 127.0.0.1): `smtrain fit --nproc 2`."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from smspace.train.distributed import INTERRUPTED, PEER_LOST
from smspace.train.launch import _cause
from smspace.train.run_dir import RunDir, RunView
from tests.conftest import BIN, SAMPLES
from tests.servers import assert_loopback_only, stop_group, tree

pytestmark = pytest.mark.slow
DATASET = SAMPLES / "grid-seed0-MEM"


def fit(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "smtrain"), "fit", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        **kwargs,
    )


def test_two_ranks_train_one_run_with_identical_weights_on_loopback_only(tmp_path):
    out = tmp_path / "run"
    proc = fit(DATASET, "--nproc", 2, "--steps", 120, "--eval-every", 40, "--out", out)
    seen, pids = 0, set()
    try:
        while proc.poll() is None:  # every socket of the launcher and its ranks: 127.0.0.1 only
            pids |= tree(proc.pid)
            seen = max(seen, assert_loopback_only(tree(proc.pid)))
            time.sleep(0.2)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        stop_group(proc)
    assert proc.returncode == 0, stderr
    assert seen >= 3  # the store, and gloo on each rank
    assert stdout.count("run: ") == 1  # rank 0 alone speaks
    run = RunDir.open(out)
    assert run.view.config.world_size == 2 and run.view.config.batch_size == 100
    assert [r["step"] for r in run.view.metrics()] == [0, 40, 80, 120]  # written once, by rank 0
    status = run.view.status()
    assert status.state == "finished" and status.message == "2 ranks, identical weights at every evaluation"
    assert not [p for p in pids if tree(p)]  # no rank outlives the command


def test_killed_two_rank_run_resumes_on_two_ranks_only(tmp_path):
    out = tmp_path / "run"
    args = [DATASET, "--nproc", 2, "--steps", 1000, "--eval-every", 50, "--out", out]
    proc = fit(*args)
    try:
        deadline = time.monotonic() + 300
        while not ((out / "checkpoint.pt").exists() and RunView.open(out).checkpoint_step() >= 100):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        stop_group(proc)
    killed_at = RunView.open(out).checkpoint_step()
    assert 100 <= killed_at < 1000

    alone = subprocess.run(
        [str(BIN / "smtrain"), "fit", "--resume", str(out)], capture_output=True, text=True, timeout=120
    )
    assert alone.returncode == 2 and alone.stderr.count("\n") == 1
    assert "trained on 2 process(es)" in alone.stderr

    again = fit("--resume", out, "--nproc", 2)
    stdout, stderr = again.communicate(timeout=300)
    assert again.returncode == 0, stderr
    steps = [r["step"] for r in RunView.open(out).metrics()]
    assert steps == list(range(0, 1001, 50))  # no step lost, none written twice
    assert json.loads(stdout.splitlines()[-1])["step"] == 1000


def test_a_global_batch_that_does_not_split_is_one_line(tmp_path):
    proc = fit(DATASET, "--nproc", 2, "--batch-size", 101, "--steps", 10, "--out", tmp_path / "run")
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--batch-size 101" in lines[0], stderr
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_rank_zeros_own_failure_is_the_cause_whichever_rank_ended_first():
    """Both ranks stop on a NaN; rank 1 may abort (SIGABRT) while the process group comes down,
    before rank 0 has exited with its error (seen in a CI run): rank 0's failure is what
    stopped the run, not the abort, and rank 0 has already said why."""
    abort = -signal.SIGABRT
    assert _cause([(1, abort), (0, 1)]) == (0, 1)
    assert _cause([(0, 1), (1, abort)]) == (0, 1)
    assert _cause([(1, abort), (0, PEER_LOST)]) == (1, abort)  # rank 0 only lost its peer: the abort is the cause
    assert _cause([(1, 2), (0, PEER_LOST)]) == (1, 2)
    # seen together in one poll, rank 0 first: rank 1's interruption is still the cause
    assert _cause([(0, PEER_LOST), (1, INTERRUPTED)]) == (1, INTERRUPTED)


def test_a_nan_on_the_ranks_stops_every_rank_at_once(tmp_path):
    out = tmp_path / "run"
    proc = fit(
        DATASET, "--nproc", 2, "--lr-start", 1e30, "--lr-end", 1e30, "--steps", 200, "--eval-every", 50, "--out", out
    )
    _, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 1, stderr
    lines = [ln for ln in stderr.splitlines() if "error" in ln]
    assert len(lines) == 1 and "NaN" in lines[0], stderr
    status = RunView.open(out).status()
    assert status.state == "failed" and "NaN" in status.message


def signalled_two_rank_run(out, signum: int, pid_of) -> tuple[subprocess.Popen, dict[int, int], str]:
    """A long two-rank run, sent `signum` once its first checkpoint exists: to the process
    `pid_of({rank: pid})` names, the launcher for 0. Returns the launcher, the ranks' pids, its stderr."""
    import psutil

    proc = fit(DATASET, "--nproc", 2, "--steps", 100000, "--eval-every", 50, "--out", out)
    try:
        deadline = time.monotonic() + 120
        while not (out / "checkpoint.pt").exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        ranks = {int(p.environ()["RANK"]): p.pid for p in psutil.Process(proc.pid).children()}
        os.kill(pid_of(ranks) or proc.pid, signum)
        _, stderr = proc.communicate(timeout=60)
    finally:
        stop_group(proc)
    return proc, ranks, stderr


@pytest.mark.parametrize("victim", [1, 0])
def test_a_rank_killed_outright_is_named_in_one_line_and_in_the_status(tmp_path, victim):
    """kill -9 of rank 1 gave 51 lines of gloo traceback on rank 0 (and its status stored them);
    kill -9 of rank 0 printed nothing, exited 247 and left the status "running"."""
    out = tmp_path / "run"
    proc, ranks, stderr = signalled_two_rank_run(out, signal.SIGKILL, lambda ranks: ranks[victim])
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    expected = f"smtrain: error: rank {victim} (pid {ranks[victim]}) was killed by SIGKILL; its checkpoint of step"
    assert proc.returncode == 137 and len(lines) == 1 and lines[0].startswith(expected), stderr
    assert lines[0].endswith(f"smtrain fit --resume {out} --nproc 2")
    status = RunView.open(out).status()
    assert status.state == "failed" and status.message == lines[0].removeprefix("smtrain: error: ")


@pytest.mark.parametrize("target", ["launcher", "rank 0", "rank 1"])
def test_sigterm_to_a_two_rank_run_says_interrupted_once(tmp_path, target):
    """SIGTERM to the launcher printed its interrupted line twice (rank 0's and the launcher's)."""
    out = tmp_path / "run"

    def pid(ranks: dict[int, int]) -> int:
        return ranks[int(target[-1])] if target.startswith("rank") else 0  # 0: the launcher

    proc, _, stderr = signalled_two_rank_run(out, signal.SIGTERM, pid)
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert proc.returncode == 130 and len(lines) == 1 and lines[0].startswith("interrupted"), stderr
    assert "is kept: smtrain fit --resume" in lines[0] and lines[0].endswith(f"{out} --nproc 2"), stderr
    assert RunView.open(out).status().state == "interrupted"


@pytest.mark.parametrize(
    "raised, kind, needle",
    [
        (RuntimeError("[gloo/transport/tcp/pair.cc:534] Connection closed by peer [127.0.0.1]:4032"), "PeerLost",
         "rank 1 lost another rank of this run"),
        (RuntimeError("DefaultCPUAllocator: not enough memory: you tried to allocate 85899345920 bytes."),
         "RankFailed", "rank 1 failed: RuntimeError: DefaultCPUAllocator: not enough memory"),
        (RuntimeError("The size of tensor a (5) must match the size of tensor b (4) at non-singleton dimension 1"),
         "RankFailed", "rank 1 failed: RuntimeError: The size of tensor a (5) must match"),
    ],
)  # fmt: skip
def test_a_rank_s_own_error_is_its_cause_not_a_lost_peer(raised, kind, needle):
    """peer_errors called every RuntimeError of a rank a lost peer: an out-of-memory or a model's
    shape error became "rank N exited with 3" and its cause was lost."""
    from smspace.train.distributed import Ranks, peer_errors

    with pytest.raises(Exception) as caught, peer_errors(Ranks(1, 2)):
        raise raised
    assert type(caught.value).__name__ == kind and needle in str(caught.value), caught.value
    assert "\n" not in str(caught.value)
