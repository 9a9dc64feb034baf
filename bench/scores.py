"""A trained run's row of a task (its world, mode, step and wall time) and the h it is scored on;
the scores themselves are declared in metrics/scores.py."""

from __future__ import annotations

from typing import Any

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.lake.store import Store
from smspace.train.run_dir import RunView


def run_scores(run: RunView, steps: int, lake: Store) -> tuple[dict[str, Any], np.ndarray]:
    """A trained run's row (its world, mode, step and wall time) and the h its scores are computed
    from: that of its last evaluation, which must be the task's last step. The world and mode are
    those its dataset's manifest records it was generated with, never read back from a name."""
    rows = run.metrics()
    last = rows[-1]
    if last["step"] != steps:
        raise SmspaceError(f"{run.name} ended at step {last['step']}, not the task's {steps}")
    h, _ = run.embeddings(last["step"])
    made = Dataset.open(run.config.dataset_id, lake).manifest
    row = {"world": made.world_seed, "mode": made.mode, "step": last["step"], "wall_s": last["elapsed_s"]}
    return row | {"run": run.name}, h


def evaluation_steps(steps: int, eval_every: int) -> list[int]:
    """The evaluations a task's protocol makes before its last step: 0, eval_every, 2 eval_every, …"""
    return list(range(0, steps, eval_every))


def run_curve(run: RunView, steps: int, eval_every: int) -> list[tuple[int, np.ndarray]]:
    """h of every evaluation a trained run made before the task's last step, in order: the scores
    its budget is judged on. They must be exactly the protocol's evaluations."""
    made = [row["step"] for row in run.metrics() if row["step"] < steps]
    if made != evaluation_steps(steps, eval_every):
        raise SmspaceError(f"{run.name} was evaluated at steps {made}, not the protocol's "
                           f"{evaluation_steps(steps, eval_every)}")  # fmt: skip
    return [(step, run.embeddings(step)[0]) for step in made]
