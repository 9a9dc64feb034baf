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
from datagen.generate import generate
from datagen.setups import get_setup
from lake.catalog import check_lake
from lake.manifest import load_manifest
from lake.store import Store
from train.config import TrainConfig
from train.ensemble import train_ensemble
from train.run_dir import CONFIG, RunDir

# What a re-run may change: more steps extend a study, with the learning-rate schedule as recorded.
RESUMABLE = ("steps", "lr_decay_steps")


def plan_runs(template: TrainConfig, datasets: list[Store], out: Path, overwrite: bool) -> list[tuple[RunDir, int]]:
    """(run folder, step it is at) for every dataset; creates new folders, checks old ones."""
    plans = []
    for folder in datasets:
        manifest = load_manifest(folder)
        cfg = replace(template, seed=manifest.world_seed).for_dataset(folder, manifest)
        path = out / cfg.run_name
        if (path / CONFIG).exists() and not overwrite:
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
    out: Path,
    transitions: int | None = None,
    gen_workers: int = 1,
    max_ensemble: int = 150,
    overwrite: bool = False,
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
    for step, runs in sorted(by_step.items()):
        for i in range(0, len(runs), max_ensemble):
            train_ensemble(runs[i : i + max_ensemble], resume=step > 0, threads=template.threads)
    return [run for run, _ in plans]
