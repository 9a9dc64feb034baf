"""Running a function over tasks in other processes: a local spawn pool, or Ray. Shared by
generation (one task per shard) and sweeps (one task per ensemble); no scheduling of our own.

Both stop everything they started when the command fails or is interrupted, and both give errors
back as one line."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from typing import Any

from common.cli import die_with_parent
from common.errors import SmspaceError


def in_processes(fn: Callable, tasks: list[tuple], workers: int) -> Iterator[tuple[tuple, Any]]:
    """(task, fn(*task)) in completion order, from `workers` spawned processes (SAPIEN hangs in
    forked children, torch dislikes them). An error, Ctrl-C or SIGTERM kills the workers at once."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=die_with_parent, initargs=(signal.SIGKILL, os.getpid())
    ) as pool:
        try:
            futures = {pool.submit(fn, *task): task for task in tasks}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for f in done:
                    yield futures[f], f.result()  # re-raises a worker's error here, after cleanup
        except BaseException:  # stop the workers now, not after their current task
            for process in list(pool._processes.values()):
                process.kill()
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def import_ray(flag: str = "--executor ray"):
    try:
        import ray
    except ImportError:
        raise SmspaceError(f"{flag} needs Ray: pip install 'smspace[cluster]'") from None
    return ray


@contextlib.contextmanager
def ray_session(cpus: int) -> Iterator[Any]:
    """Ray, joined at $RAY_ADDRESS or started here on `cpus` CPUs, bound to 127.0.0.1 without a
    dashboard; a Ray started here is stopped on the way out (with all its processes)."""
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    address = os.environ.get("RAY_ADDRESS")
    try:
        if address:
            ray.init(address=address, log_to_driver=False, logging_level="ERROR")
        else:
            ray.init(
                num_cpus=cpus,
                include_dashboard=False,
                _node_ip_address="127.0.0.1",
                log_to_driver=False,
                logging_level="ERROR",
            )
    except Exception as e:
        raise SmspaceError(f"cannot start or join Ray ({address or 'local'}): {_line(e)}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def in_ray(ray, remote_fn, tasks: list[tuple]) -> Iterator[tuple[tuple, Any]]:
    """(task, result) in completion order from a Ray remote function; an error or interrupt cancels
    the tasks still running."""
    refs = {remote_fn.remote(*task): task for task in tasks}
    try:
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield refs[ref], ray_get(ray, ref)
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise


def ray_get(ray, ref):
    """A task's result; its SmspaceError comes back as itself, any other failure as one line."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        original = getattr(e, "cause", None)
        if isinstance(original, SmspaceError):
            raise SmspaceError(str(original)) from None
        raise SmspaceError(f"a Ray task failed: {_line(original or e)}") from None
    except ray.exceptions.RayError as e:
        raise SmspaceError(f"a Ray task failed: {_line(e)}") from None


def _line(e: BaseException) -> str:
    return " ".join(str(e).split())[:300] or type(e).__name__
