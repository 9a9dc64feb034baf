"""How `smtrain fit` runs on one process or many: the ranks started (`--nproc N`, without
torchrun) or joined (under torchrun), the run folder prepared by rank 0 alone, and a stop said once.

torchrun --standalone does the same, but its rendezvous store listens on every interface; this
launcher hosts the store itself on a socket bound to 127.0.0.1 (PyTorch's TCPStore accepts a
listening socket), sets gloo to the loopback interface, and starts the ranks as plain
processes that die with it. Everything else is PyTorch's: the ranks join with
init_process_group and train under DistributedDataParallel (train/distributed.py).
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from datetime import timedelta
from functools import partial
from typing import NoReturn

import torch.distributed as dist

from smspace.common.cli import die_with_parent
from smspace.common.errors import Interrupted, SmspaceError
from smspace.train.distributed import (
    INTERRUPTED,
    PEER_LOST,
    STORE_ENV,
    PeerLost,
    Ranks,
    all_ok,
    join_from_environment,
    leave,
)
from smspace.train.fit import FitPlan
from smspace.train.run_dir import RunDir, after_a_stop

GRACE_S = 5.0  # a rank that failed waits this long for rank 0 to fail the same way and say why


def launch_if_asked(nproc: int, plan_for: Callable[[int], FitPlan]) -> None:
    """With --nproc N outside a launched rank: check the run for N ranks, start them, exit with
    their outcome (this process only launches). Otherwise return and let this process train."""
    if nproc <= 1 or STORE_ENV in os.environ:
        return
    if "WORLD_SIZE" in os.environ:
        raise SmspaceError("--nproc launches its own processes; under torchrun use --nproc-per-node instead")
    plan = plan_for(nproc)  # refused before any rank starts
    with resume_hint(plan.where, nproc):
        sys.exit(launch_local(nproc, [sys.executable, "-m", "smspace.cli", *sys.argv[1:]], plan.where))


@contextlib.contextmanager
def rank_of(plan: FitPlan, say: Callable[[str], None]) -> Iterator[tuple[Ranks, RunDir]]:
    """This process's rank of the run (the only one, or one of torchrun's or the launcher's), with
    the run folder rank 0 prepared; a rank that failed never leaves the others waiting, and a stop
    is said once: by rank 0, or by the launcher of --nproc."""
    ranks = join_from_environment(plan.cfg.device)
    launched = STORE_ENV in os.environ
    try:
        run, problem = None, None
        if ranks.primary:
            if plan.change:
                say(plan.change)
            run, problem = _attempt(plan.start)
        if not all_ok(problem is None, ranks):  # no rank waits forever for a rank 0 that gave up
            raise problem or SmspaceError("rank 0 could not prepare the run folder (see its error)")
        speaks = ranks.primary and not launched
        with resume_hint(plan.where, ranks.world) if speaks else contextlib.nullcontext():
            yield ranks, run or RunDir(plan.where)
    except KeyboardInterrupt:
        if launched:
            _leave_now(INTERRUPTED)  # the run's status says it; the launcher prints the line
        raise
    except PeerLost:
        if launched:  # the launcher names the rank that died, in one line
            _leave_now(PEER_LOST)
        raise  # under torchrun this rank says it
    finally:
        leave(ranks)


def _leave_now(code: int) -> NoReturn:
    """A launched rank stopped early exits at once, skipping gloo's teardown (the process group's,
    and DDP's at interpreter exit): with the other rank's collective still pending, that teardown
    aborted now and then under load (SIGABRT, CI). Nothing is left to do: rank 0 recorded the
    status on its way here, the claims are released, and the launcher prints the line."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


@contextlib.contextmanager
def resume_hint(where: str, world: int) -> Iterator[None]:
    """Ctrl-C or SIGTERM: say which step the kept checkpoint holds and the command that resumes."""
    try:
        yield
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted; {after_a_stop(where, world)}") from None


def _attempt(action: Callable[[], RunDir]) -> tuple[RunDir | None, SmspaceError | None]:
    """(what the action returned, None), or (None, its error): the error is raised only once every
    rank knows about it."""
    try:
        return action(), None
    except SmspaceError as e:
        return None, e


def _store_on_loopback(nproc: int) -> tuple[dist.TCPStore, int]:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    port = sock.getsockname()[1]
    store = dist.TCPStore(  # owns the listening socket from here on
        "127.0.0.1",
        port,
        nproc,
        is_master=True,
        master_listen_fd=sock.detach(),
        use_libuv=False,  # the libuv server ignores a given socket
        wait_for_workers=False,
        timeout=timedelta(minutes=30),
    )
    return store, port


def launch_local(nproc: int, argv: list[str], where: str) -> int:
    """Run `argv` as `nproc` ranks; returns 0, or the exit code of the rank whose failure stopped
    the run (the others are stopped). Rank 0 speaks (progress, result, its own error); a rank that
    only lost contact with another one exits quietly (PEER_LOST), and this launcher then names, in
    one line, the rank that died and how to resume the run in `where`."""
    store, port = _store_on_loopback(nproc)
    env = {**os.environ, STORE_ENV: f"127.0.0.1:{port}", "WORLD_SIZE": str(nproc), "LOCAL_WORLD_SIZE": str(nproc)}
    env.setdefault("GLOO_SOCKET_IFNAME", "lo")
    env.setdefault("OMP_NUM_THREADS", "1")
    with tempfile.TemporaryDirectory(prefix="smtrain-ranks-") as logs:
        errs = [None] + [open(os.path.join(logs, f"rank{r}.err"), "w+") for r in range(1, nproc)]  # noqa: SIM115
        procs = [
            subprocess.Popen(  # each rank dies with this process, however it dies
                argv,
                env={**env, "RANK": str(r), "LOCAL_RANK": str(r)},
                stderr=errs[r],
                preexec_fn=partial(die_with_parent, signal.SIGKILL, os.getpid()),
            )
            for r in range(nproc)
        ]
        try:
            exits = _wait(procs)
        except BaseException:  # Ctrl-C or SIGTERM here: the ranks stop too
            for p in procs:
                p.send_signal(signal.SIGTERM)
            for p in procs:
                p.wait()
            raise
        finally:
            del store
        cause = _cause(exits)
        if cause is None:
            return 0
        rank, code = cause
        if procs[0].returncode == 0:  # the run finished (weights compared at every evaluation, the last
            # included); another rank failing while the process group was torn down cannot touch it
            print(f"smtrain: note: rank {rank} ended with {_how(code)} after the run finished", file=sys.stderr)
            return 0
        if rank == 0:  # rank 0 said why; a rank killed as the group came down is only noted
            for other, how in exits:
                if other != 0 and how < 0 and how != -signal.SIGTERM:
                    print(f"smtrain: note: rank {other} ended with {_how(how)} as the run stopped", file=sys.stderr)
        if code == INTERRUPTED:  # a rank stopped by Ctrl-C or SIGTERM sent to it, not to this launcher
            line = f"interrupted (rank {rank}); {after_a_stop(where, nproc)}"
            print(line, file=sys.stderr)
            _record_outcome(where, line, "interrupted")
            return code
        if code < 0:  # died by a signal: nothing of it could speak or record its end
            killed = f"rank {rank} (pid {procs[rank].pid}) was killed by {_how(code)}"
            line = f"{killed}; {after_a_stop(where, nproc)}"
            print(f"smtrain: error: {line}", file=sys.stderr)
            _record_outcome(where, line)
            return 128 - code
        if rank != 0 and procs[0].returncode in (0, PEER_LOST, -signal.SIGTERM, INTERRUPTED):
            errs[rank].seek(0)
            lines = [ln for ln in errs[rank].read().splitlines() if ln.strip()]
            print(
                f"{lines[-1] if lines else f'smtrain: error: rank {rank} exited with {code}'} (rank {rank})",
                file=sys.stderr,
            )
        return code


def _wait(procs: list[subprocess.Popen]) -> list[tuple[int, int]]:
    """Wait for every rank; (rank, exit code) in the order they ended. On the first failure give
    rank 0 a moment to end the same way and say why, then stop the rest."""
    exits: list[tuple[int, int]] = []
    deadline = None
    while len(exits) < len(procs):
        for r, p in enumerate(procs):
            if p.poll() is not None and r not in {e[0] for e in exits}:
                exits.append((r, p.returncode))
                if p.returncode != 0 and deadline is None:
                    deadline = time.monotonic() + GRACE_S
        if deadline is not None and time.monotonic() > deadline:
            for p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            deadline = float("inf")
        time.sleep(0.05)
    return exits


def _cause(exits: list[tuple[int, int]]) -> tuple[int, int] | None:
    """The failure that stopped the run: the first one that is not only a lost contact (a rank
    whose peer died) nor our own SIGTERM to the ranks left running."""
    failures = [(r, c) for r, c in exits if c != 0]
    own = [(r, c) for r, c in failures if c not in (PEER_LOST, -signal.SIGTERM, INTERRUPTED)]
    said = [(r, c) for r, c in own if r == 0 and c > 0]  # rank 0 failed by itself (a lost peer would
    # be PEER_LOST) and said why; another rank dying as the group came down did not cause it
    interrupted = [(r, c) for r, c in failures if c == INTERRUPTED]  # before the peer that lost it,
    # whichever the launcher saw end first
    return (said or own or interrupted or failures or [None])[0]


def _how(code: int) -> str:
    """A rank's exit code as a reader wants it: the signal's name, or the code."""
    return signal.Signals(-code).name if code < 0 else f"code {code}"


def _record_outcome(where: str, line: str, state: str = "failed") -> None:
    """The run's status, which a rank killed outright never wrote, or which a rank that lost its
    interrupted peer wrote as its own failure (best effort, within seconds)."""
    from smspace.common.bounded import run_within

    def mark() -> None:
        run = RunDir.open(where)
        run.set_status(state, run.view.status().step, line)

    run_within([mark])
