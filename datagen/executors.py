"""Where the parts of a generation run: this process, a pool of local processes, or Ray.

An executor takes (config, folder, part) tasks and returns their PartRecords; the bytes never
depend on which one ran them. We schedule nothing ourselves beyond a local process pool: a
cluster is Ray's job (or a SLURM array's, through --rank/--world-size).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from dataclasses import dataclass

from tqdm import tqdm

from common.cli import die_with_parent
from common.errors import SmspaceError
from datagen.parts import PartRecord, preflight, write_part
from lake.manifest import GenConfig
from lake.store import Store

EXECUTORS = ("local", "ray")
Task = tuple[GenConfig, Store, int]


@dataclass(frozen=True)
class ExecutorOptions:
    workers: int = 1  # local processes, or CPUs of a local Ray started here
    gpus_per_task: float = 0.0  # Ray only: GPUs each part asks for (SAPIEN on CUDA)
    max_retries: int = 3  # Ray only: a part whose worker died is run again this often


def _transitions(task: Task) -> int:
    cfg, _, part = task
    if part < 0:
        return 0
    lo, hi = cfg.shard_range(part)
    return hi - lo


Runner = Callable[[list[Task]], list[tuple[Task, PartRecord]]]


@contextlib.contextmanager
def open_executor(executor: str, setup: str, options: ExecutorOptions) -> Iterator[Runner]:
    """A runner of tasks, once the setup's pre-flight passed where the parts will run (before
    anything is written). The runner runs every task, in any order; an error stops the others and
    is raised in one line."""
    if executor == "local":
        preflight(setup)
        yield _progress(lambda tasks: _run_local(tasks, options))
    elif executor == "ray":
        ray = _import_ray()
        leave = _ray_session(ray, options)
        try:
            # the driver may have no Vulkan: the setup's pre-flight runs where the parts will
            check = ray.remote(num_cpus=1, num_gpus=options.gpus_per_task, max_retries=options.max_retries)(preflight)
            _ray_get(ray, check.remote(setup))
            yield _progress(lambda tasks: _run_ray(ray, tasks, options))
        finally:
            leave()
    else:
        raise SmspaceError(f"unknown --executor {executor!r} (one of {', '.join(EXECUTORS)})")


def _progress(run: Callable[[list[Task]], Iterator[tuple[Task, PartRecord]]]) -> Runner:
    def runner(tasks: list[Task]) -> list[tuple[Task, PartRecord]]:
        total = sum(_transitions(t) for t in tasks)
        with tqdm(total=total, unit="tr", unit_scale=True, disable=None, file=sys.stderr, desc="generating") as bar:
            done = []
            for task, record in run(tasks):
                done.append((task, record))
                bar.update(_transitions(task))
            return done

    return runner


def _run_local(tasks: list[Task], options: ExecutorOptions) -> Iterator[tuple[Task, PartRecord]]:
    if options.workers <= 1 or sum(_transitions(t) > 0 for t in tasks) <= 1:  # no pool for one shard
        for task in tasks:
            yield task, write_part(*task)
        return
    ctx = multiprocessing.get_context("spawn")  # SAPIEN hangs in forked children
    with ProcessPoolExecutor(
        max_workers=options.workers, mp_context=ctx, initializer=die_with_parent, initargs=(signal.SIGKILL, os.getpid())
    ) as pool:
        try:
            futures = {pool.submit(write_part, *task): task for task in tasks}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for f in done:
                    yield futures[f], f.result()  # re-raises a worker's error here, after cleanup
        except BaseException:  # an error, Ctrl-C or SIGTERM: stop the workers now, not after their shards
            for process in list(pool._processes.values()):
                process.kill()
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def _import_ray():
    try:
        import ray
    except ImportError:
        raise SmspaceError("--executor ray needs Ray: pip install 'smspace[cluster]'") from None
    return ray


def _ray_session(ray, options: ExecutorOptions) -> Callable[[], None]:
    """Join the cluster at $RAY_ADDRESS, or start a local Ray bound to 127.0.0.1 on this machine's
    cores; returns how to leave it (a local Ray started here is stopped)."""
    if ray.is_initialized():
        return lambda: None
    address = os.environ.get("RAY_ADDRESS")
    try:
        if address:
            ray.init(address=address, log_to_driver=False, logging_level="ERROR")
        else:
            ray.init(
                num_cpus=options.workers,
                include_dashboard=False,
                _node_ip_address="127.0.0.1",
                log_to_driver=False,
                logging_level="ERROR",
            )
    except Exception as e:
        raise SmspaceError(
            f"cannot start or join Ray ({address or 'local'}): {' '.join(str(e).split())[:200]}"
        ) from None
    return ray.shutdown


def _run_ray(ray, tasks: list[Task], options: ExecutorOptions) -> Iterator[tuple[Task, PartRecord]]:
    # GPU tasks default to max_calls=1 (a fresh worker, hence a fresh SAPIEN room, per part)
    part_task = ray.remote(
        num_cpus=1,
        num_gpus=options.gpus_per_task,
        max_retries=options.max_retries,
        retry_exceptions=False,
        max_calls=0,
    )(write_part)
    refs = {part_task.remote(*task): task for task in tasks}
    try:
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield refs[ref], _ray_get(ray, ref)
    except BaseException:  # an error, Ctrl-C or SIGTERM: the other parts stop now
        for ref in refs:
            ray.cancel(ref, force=True)
        raise


def _ray_get(ray, ref):
    """A task's result; its SmspaceError comes back as itself, any other failure as one line."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = e.as_instanceof_cause() if hasattr(e, "as_instanceof_cause") else e
        original = getattr(e, "cause", None)
        if isinstance(original, SmspaceError):
            raise SmspaceError(str(original)) from None
        raise SmspaceError(f"a Ray task failed: {' '.join(str(cause).split())[:300]}") from None
    except ray.exceptions.RayError as e:
        raise SmspaceError(f"a Ray task failed: {' '.join(str(e).split())[:300]}") from None
