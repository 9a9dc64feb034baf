"""Where the parts of a generation run: this process, a pool of local processes, or Ray.

An executor takes (config, folder, part) tasks and returns their PartRecords; the bytes never
depend on which one ran them. We schedule nothing ourselves beyond a local process pool: a
cluster is Ray's job (or a SLURM array's, through --rank/--world-size).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from smspace.common.executors import WorkerDied
from smspace.common.executors import open_executor as shared_executor
from smspace.common.progress import Progress
from smspace.datagen.parts import PartRecord, preflight, write_part
from smspace.lake.manifest import GenConfig
from smspace.lake.store import Store

Task = tuple[GenConfig, Store, int]
Runner = Callable[[list[Task]], list[tuple[Task, PartRecord]]]


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


@contextlib.contextmanager
def open_part_writers(
    executor: str, setup: str, options: ExecutorOptions, probe_world: int | None = None
) -> Iterator[Runner]:
    """A runner of tasks, once the setup's pre-flight passed where the parts will run (before
        anything is written; on Ray, on a worker: the driver may have no Vulkan), with world `probe_world`
    held to the setup contract. The runner runs every
        task, in any order; an error stops the others and is raised in one line."""
    ray_options = {"num_cpus": 1, "num_gpus": options.gpus_per_task, "max_retries": options.max_retries}
    # GPU tasks default to max_calls=1 (a fresh worker, hence a fresh SAPIEN room, per part)
    with shared_executor(executor, options.workers, **ray_options, retry_exceptions=False, max_calls=0) as ex:
        ex.call(preflight, setup, probe_world)
        yield _progress(lambda tasks: ex.map(write_part, tasks))


def _progress(run: Callable[[list[Task]], Iterator[tuple[Task, PartRecord]]]) -> Runner:
    def runner(tasks: list[Task]) -> list[tuple[Task, PartRecord]]:
        total = sum(_transitions(t) for t in tasks)
        bar = Progress("generating", total, "transition", enabled=total > 0)
        done = []
        try:
            for task, record in run(tasks):
                done.append((task, record))
                bar.update(_transitions(task))
        except WorkerDied as e:
            kept = "the parts already stored are kept: the same command completes the datasets"
            raise WorkerDied(f"{e}; {kept}") from None
        finally:
            bar.close()
        return done

    return runner
