"""`smtrain sweep`: every (world, mode) run of a study, generated if missing, trained as ensembles.

Run folders are the ones `smtrain fit` writes (so ls, info, view, report and fit --resume all work
on them). A sweep re-run continues where it stopped: finished runs are skipped, the others resume
from their checkpoints, grouped by the step they reached.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace
from pathlib import Path

from common.errors import SmspaceError
from common.executors import in_processes, in_ray, ray_session
from datagen.generate import generate
from datagen.setups import get_setup
from lake.catalog import check_lake
from lake.manifest import load_manifest
from lake.store import Store, open_store
from train.config import TrainConfig
from train.ensemble import train_ensemble
from train.run_dir import CONFIG, RunDir

# What a re-run may change: more steps extend a study, with the learning-rate schedule as recorded.
RESUMABLE = ("steps", "lr_decay_steps")


def plan_runs(
    template: TrainConfig, datasets: list[Store], out: Store | Path | str, overwrite: bool
) -> list[tuple[RunDir, int]]:
    """(run folder, step it is at) for every dataset; creates new folders, checks old ones."""
    out = out if isinstance(out, Store) else open_store(out)
    plans = []
    for folder in datasets:
        manifest = load_manifest(folder)
        cfg = replace(template, seed=manifest.world_seed).for_dataset(folder, manifest)
        path = out.child(cfg.run_name)
        if path.exists(CONFIG) and not overwrite:
            run = RunDir.open(path)
            old = run.config.to_dict()
            new = cfg.to_dict()
            diff = [k for k in new if k not in RESUMABLE and old.get(k) != new[k]]
            if diff:
                raise SmspaceError(f"{path} holds a run with another {', '.join(diff)}; pass --overwrite or --out")
            if old["steps"] != new["steps"]:  # extending a study: the schedule stays as recorded
                run.write_config(replace(run.config, steps=cfg.steps))
            step = run.checkpoint_step()
            if step == 0:  # killed before its first checkpoint: start it afresh
                run = RunDir.create(path, cfg, overwrite=True)
        else:
            run, step = RunDir.create(path, cfg, overwrite), 0
        plans.append((run, step))
    return plans


def sweep(
    setup: str,
    modes: list[str],
    world_seeds: list[int],
    template: TrainConfig,
    lake: Store | str,
    out: Store | Path | str,
    transitions: int | None = None,
    gen_workers: int = 1,
    max_ensemble: int = 150,
    overwrite: bool = False,
    executor: str = "local",
    workers: int = 1,
) -> list[RunDir]:
    spec = get_setup(setup)
    n = spec.default_transitions if transitions is None else transitions
    results = generate(lake, setup, modes, world_seeds, n, spec.default_shard_size, workers=gen_workers)
    datasets = [check_lake(lake).child(m.dataset_id) for m, _ in results]
    plans = plan_runs(template, datasets, out, overwrite)
    by_step: dict[int, list[RunDir]] = defaultdict(list)
    for run, step in plans:
        if step < run.config.steps:
            by_step[step].append(run)
    chunks = [
        (chunk, step > 0) for step, runs in sorted(by_step.items()) for chunk in ensembles(runs, max_ensemble, workers)
    ]
    run_ensembles(chunks, executor, workers, template.threads, template.device)
    return [run for run, _ in plans]


def ensembles(runs: list[RunDir], max_ensemble: int, workers: int) -> list[list[RunDir]]:
    """Runs cut into ensembles of at most max_ensemble, and into at least `workers` of them when
    there are enough runs, so that every core (or Ray CPU) gets one. A run's weights do not depend
    on the grouping (docs/MODEL.md §4: only the summation order of the batched matmuls differs)."""
    size = max(1, min(max_ensemble, -(-len(runs) // max(1, workers))))
    return [runs[i : i + size] for i in range(0, len(runs), size)]


def train_chunk(paths: list[str], resume: bool, threads: int, progress: bool = False) -> int:
    """One ensemble, wherever it runs (this process, a spawned one, a Ray worker); returns its size."""
    runs = [RunDir.open(p) for p in paths]
    train_ensemble(runs, resume=resume, threads=threads, progress=progress)
    return len(runs)


def run_ensembles(
    chunks: list[tuple[list[RunDir], bool]], executor: str, workers: int, threads: int, device: str
) -> None:
    """Train every ensemble: in this process when there is one (or one worker), else one spawned
    process per ensemble up to `workers` at a time, or one Ray task per ensemble."""
    if executor not in ("local", "ray"):
        raise SmspaceError(f"unknown --executor {executor!r} (local or ray)")
    if executor == "local" and (workers <= 1 or len(chunks) <= 1):
        for runs, resume in chunks:
            train_ensemble(runs, resume=resume, threads=threads)
        return
    for runs, _ in chunks:  # the processes that train them claim them
        for run in runs:
            run.release()
    tasks = [([str(run.path) for run in runs], resume, threads) for runs, resume in chunks]
    if executor == "local":
        for _ in in_processes(train_chunk, tasks, workers):
            pass
        return
    with ray_session(workers) as ray:
        # no retry: a task started again would not know how far it got; re-running the sweep resumes
        remote = ray.remote(num_cpus=threads, num_gpus=1 if device.startswith("cuda") else 0, max_retries=0)
        for _ in in_ray(ray, remote(train_chunk), tasks):
            pass
