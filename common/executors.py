"""Running a function over tasks in other processes: a local spawn pool, or Ray. Shared by
generation (one task per shard) and sweeps (one task per ensemble); no scheduling of our own.

Both stop everything they started when the command fails or is interrupted, and both give errors
back as one line."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import signal
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.managers import SyncManager
from pathlib import Path
from typing import Any

from smspace.common.cli import EXECUTORS, die_with_parent
from smspace.common.errors import SmspaceError, one_line


class WorkerDied(SmspaceError):
    """A worker process ended outside our control (killed, out of memory); callers add what was
    kept and the command that continues."""

    exit_code = 1


POLL_S = 0.5  # how often the workers are looked at: a spawn pool never notices a killed one (CPython 3.11)


def in_processes(fn: Callable, tasks: list[tuple], workers: int) -> Iterator[tuple[tuple, Any]]:
    """(task, fn(*task)) in completion order, from `workers` spawned processes (SAPIEN hangs in
    forked children, torch dislikes them). An error, Ctrl-C or SIGTERM kills the workers at once;
    a worker that dies is named in a WorkerDied."""
    _quiet_resource_tracker()
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=die_with_parent, initargs=(signal.SIGKILL, os.getpid())
    ) as pool:
        try:
            futures = {pool.submit(fn, *task): task for task in tasks}
            pending = set(futures)
            seen: dict = {}  # every worker the pool started: it forgets them once it saw one die
            while pending:
                seen.update(pool._processes or {})
                done, pending = wait(pending, timeout=POLL_S, return_when=FIRST_EXCEPTION)
                for f in done:
                    try:
                        result = f.result()  # re-raises a worker's error here, after cleanup
                    except BrokenProcessPool:  # the pool saw a worker's pipe close before its exit was known
                        raise _dead(seen, wait_s=2.0) or WorkerDied("a worker process died") from None
                    yield futures[f], result
                died = _dead(seen | (pool._processes or {}))
                if died is not None:
                    raise died
        except BaseException:  # stop the workers now, not after their current task
            for process in list(pool._processes.values()):
                process.kill()
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def _dead(workers: dict, wait_s: float = 0.0) -> WorkerDied | None:
    """The first of the pool's workers that ended, named (a live worker has no exit code); waits up
    to `wait_s` for the exit of one that is still being torn down."""
    deadline = time.monotonic() + wait_s
    while True:
        for process in list(workers.values()):
            code = process.exitcode
            if code is not None and code != 0:
                how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with code {code}"
                return WorkerDied(f"worker process {process.pid} {how}")
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.05)


def _quiet_resource_tracker() -> None:
    """The semaphores of a killed worker make multiprocessing's resource tracker warn about "leaked
    semaphore objects" at exit; it cleans them up all the same. The tracker takes its warning
    filters from sys.warnoptions when it starts, so they are set before it does. And the tracker is
    made to survive its own death (_remember_registrations)."""
    rule = "ignore:resource_tracker:UserWarning"
    if rule not in sys.warnoptions:
        sys.warnoptions.append(rule)
    from multiprocessing import resource_tracker

    _remember_registrations(resource_tracker._resource_tracker)
    resource_tracker.ensure_running()


def _remember_registrations(tracker: Any) -> None:
    """The resource tracker is a process of its own; killed, multiprocessing starts another on the
    next call, with a warning, and that one knows none of the semaphores this process registered:
    each later unregistration printed a KeyError traceback (five after a sweep). This process
    remembers what it registered and tells a restarted tracker, so that one cleans up as the
    first would have, silently."""
    if getattr(tracker, "_smspace_live", None) is not None:
        return
    live: dict[tuple[str, str], None] = {}
    tracker._smspace_live = live
    send, ensure = tracker._send, tracker.ensure_running

    def ensure_running() -> None:
        before = tracker._pid
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="resource_tracker: process died unexpectedly")
            ensure()
        if before is not None and tracker._pid != before:  # started anew: it knows nothing yet
            for name, rtype in list(live):
                os.write(tracker._fd, f"REGISTER:{name}:{rtype}\n".encode("ascii"))

    def remembered_send(cmd: str, name: str, rtype: str) -> None:
        send(cmd, name, rtype)
        if cmd == "REGISTER":
            live[(name, rtype)] = None
        elif cmd == "UNREGISTER":
            live.pop((name, rtype), None)

    tracker.ensure_running, tracker._send = ensure_running, remembered_send


class Executor:
    """Where tasks run: this process, a pool of spawned processes, or Ray tasks. The one place the
    choice is made, for generation (a task per part) and sweeps (a task per ensemble)."""

    def __init__(self, workers: int, ray: Any = None, ray_options: dict[str, Any] | None = None):
        self.workers, self._ray, self._options = workers, ray, ray_options or {}

    def call(self, fn: Callable, *args: Any) -> Any:
        """One call where the tasks run (a pre-flight that must pass on the workers themselves)."""
        if self._ray is None:
            return fn(*args)
        return ray_get(self._ray, self._ray.remote(**self._options)(fn).remote(*args))

    @contextlib.contextmanager
    def channel(self) -> Iterator[Any]:
        """A queue the tasks can `put` small messages on (progress) and this process reads with
        `drain_channel`: a plain queue here, a multiprocessing manager's for a spawn pool, Ray's
        for Ray tasks. Passed to the tasks as an argument."""
        if self._ray is not None:
            from ray.util.queue import Queue

            ray_queue = Queue(actor_options={"num_cpus": 0})
            try:
                yield ray_queue
            finally:
                ray_queue.shutdown(force=True)
        elif self.workers <= 1:
            yield queue.SimpleQueue()
        else:
            # the manager is a process of its own: started to die with this one, however it dies
            manager = SyncManager(ctx=multiprocessing.get_context("spawn"))
            manager.start(die_with_parent, (signal.SIGKILL, os.getpid()))
            with manager:
                yield manager.Queue()

    def map(self, fn: Callable, tasks: list[tuple]) -> Iterator[tuple[tuple, Any]]:
        """(task, fn(*task)) in completion order: in this process for one worker or one task, else
        in `workers` spawned processes, or as Ray tasks."""
        if self._ray is not None:
            yield from in_ray(self._ray, self._ray.remote(**self._options)(fn), tasks)
        elif self.workers <= 1 or len(tasks) <= 1:
            for task in tasks:
                yield task, fn(*task)
        else:
            yield from in_processes(fn, tasks, self.workers)


@contextlib.contextmanager
def open_executor(kind: str, workers: int, **ray_options: Any) -> Iterator[Executor]:
    """`kind`: local (processes of this machine) or ray ($RAY_ADDRESS, else a local Ray on
    `workers` CPUs); `ray_options`: what each Ray task asks for (num_cpus, num_gpus, max_retries…)."""
    if kind == "local":
        yield Executor(workers)
    elif kind == "ray":
        with ray_session(workers) as ray:
            yield Executor(workers, ray, ray_options)
    else:
        raise SmspaceError(f"unknown --executor {kind!r} (one of {', '.join(EXECUTORS)})")


def drain_channel(channel: Any) -> list[Any]:
    """Every message waiting on an Executor.channel, without blocking."""
    items = []
    with contextlib.suppress(queue.Empty, EOFError, OSError, ConnectionError):
        while True:
            items.append(channel.get_nowait())
    return items


def import_ray(flag: str = "--executor ray"):
    try:
        import ray
    except ImportError:
        raise SmspaceError(f"{flag} needs Ray: pip install 'smspace[cluster]'") from None
    return ray


LOCAL_ONLY = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"  # "0": Ray takes 127.0.0.1 as the node's address


@contextlib.contextmanager
def ray_session(cpus: int) -> Iterator[Any]:
    """Ray, joined at $RAY_ADDRESS or started here on `cpus` CPUs without a dashboard; a Ray started
    here is a new one (never another local Ray found running), every one of its processes listens
    on 127.0.0.1 only, and it is stopped on the way out (with all its processes).

    Ray 2.60 replaces an explicit node address of 127.0.0.1 by the machine's outward address unless
    it is told that this Ray is local-only; its gcs_server, raylet and workers then bind 127.0.0.1
    instead of every interface (and the runtime-env agent 127.0.0.1 instead of the outward address)."""
    address = os.environ.get("RAY_ADDRESS")
    if not address:
        os.environ[LOCAL_ONLY] = "0"  # read when Ray is imported, and by the Ray processes started here
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    handler = signal.getsignal(signal.SIGTERM)
    try:
        if address:
            ray.init(address=address, log_to_driver=False, logging_level="ERROR")
        else:
            from ray._private import ray_constants

            ray_constants.ENABLE_RAY_CLUSTER = False  # in case Ray was imported before the variable was set
            ray.init(
                address="local",
                num_cpus=cpus,
                include_dashboard=False,
                _node_ip_address="127.0.0.1",
                log_to_driver=False,
                logging_level="ERROR",
            )
    except Exception as e:
        raise SmspaceError(f"cannot start or join Ray ({address or 'local'}): {one_line(e, limit=300)}") from None
    finally:
        signal.signal(signal.SIGTERM, handler)  # ray.init installs its own: SIGTERM must stop us as Ctrl-C does
    guard = None if address else _guard_local_ray()
    try:
        yield ray
    finally:
        ray.shutdown()
        if guard is not None:
            _release(guard)


def _guard_local_ray() -> subprocess.Popen | None:
    """A guardian (common/ray_guard.py) that stops this local Ray's processes if we are killed."""
    node = getattr(getattr(getattr(import_ray(), "_private", None), "worker", None), "_global_node", None)
    pids = [info.process.pid for infos in getattr(node, "all_processes", {}).values() for info in infos]
    if not pids:  # another Ray than the one this was written for: Ray's own cleanup is all there is
        return None
    guard = subprocess.Popen(
        [sys.executable, "-m", "smspace.common.ray_guard"],
        stdin=subprocess.PIPE,
        start_new_session=True,  # neither Ctrl-C nor our process group's signals reach it
        cwd=Path(__file__).resolve().parents[1],
    )
    guard.stdin.write("".join(f"{pid}\n" for pid in pids).encode())
    guard.stdin.flush()
    return guard


def _release(guard: subprocess.Popen) -> None:
    """Ray was stopped as it should be: the guardian leaves without touching anything."""
    with contextlib.suppress(OSError):
        guard.stdin.write(b"done\n")
        guard.stdin.close()
    try:
        guard.wait(timeout=5)
    except subprocess.TimeoutExpired:
        guard.kill()
        guard.wait()


def in_ray(ray, remote_fn, tasks: list[tuple]) -> Iterator[tuple[tuple, Any]]:
    """(task, result) in completion order from a Ray remote function; an error or interrupt cancels
    the tasks still running on a cluster we joined (a Ray started here is stopped whole; and
    cancelling a task that is finishing trips a check inside Ray 2.60)."""
    refs = {remote_fn.remote(*task): task for task in tasks}
    try:
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield refs[ref], ray_get(ray, ref)
    except BaseException:
        if os.environ.get("RAY_ADDRESS"):
            _, running = ray.wait(list(refs), num_returns=len(refs), timeout=0)
            for ref in running:
                with contextlib.suppress(Exception):
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
        raise SmspaceError(f"a Ray task failed: {one_line(original or e, limit=300)}") from None
    except ray.exceptions.RayError as e:
        raise SmspaceError(f"a Ray task failed: {one_line(e, limit=300)}") from None
