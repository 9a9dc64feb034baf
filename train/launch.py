"""`smtrain fit --nproc N`: one run as N DDP ranks on this machine, without torchrun.

torchrun --standalone does the same, but its rendezvous store listens on every interface; this
launcher hosts the store itself on a socket bound to 127.0.0.1 (PyTorch's TCPStore accepts a
listening socket), sets gloo to the loopback interface, and starts the ranks as plain
processes that die with it. Everything else is PyTorch's: the ranks join with
init_process_group and train under DistributedDataParallel (train/distributed.py).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from datetime import timedelta
from functools import partial

import torch.distributed as dist

from common.cli import die_with_parent
from train.distributed import STORE_ENV

GRACE_S = 5.0  # a rank that failed waits this long for rank 0 to fail the same way and say why


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


def launch_local(nproc: int, argv: list[str]) -> int:
    """Run `argv` as `nproc` ranks; returns 0, or the exit code of the first rank that failed (the
    others are stopped). Rank 0 speaks (progress, result, its error); another rank's error is
    shown, one line, only when rank 0 had none."""
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
            failed = _wait(procs)
        except BaseException:  # Ctrl-C or SIGTERM here: the ranks stop too
            for p in procs:
                p.send_signal(signal.SIGTERM)
            for p in procs:
                p.wait()
            raise
        finally:
            del store
        if failed is None:
            return 0
        rank, code = failed
        if rank != 0 and procs[0].returncode in (0, -signal.SIGTERM, 130):
            errs[rank].seek(0)
            lines = [ln for ln in errs[rank].read().splitlines() if ln.strip()]
            print(
                f"{lines[-1] if lines else f'smtrain: error: rank {rank} exited with {code}'} (rank {rank})",
                file=sys.stderr,
            )
        return code


def _wait(procs: list[subprocess.Popen]) -> tuple[int, int] | None:
    """Wait for every rank; on the first failure give rank 0 a moment, then stop the rest."""
    first: tuple[int, int] | None = None
    deadline = None
    while any(p.poll() is None for p in procs):
        if first is None:
            first = next(((r, p.returncode) for r, p in enumerate(procs) if p.returncode not in (None, 0)), None)
            if first is not None:
                deadline = time.monotonic() + GRACE_S
        if deadline is not None and time.monotonic() > deadline:
            for p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            deadline = None
        time.sleep(0.1)
    if first is None:
        first = next(((r, p.returncode) for r, p in enumerate(procs) if p.returncode != 0), None)
    return first
