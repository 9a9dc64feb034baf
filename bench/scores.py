"""An entry's scores on a task, run by run (one world and mode each): the paper's D_topo and
D_metric, the held-out linear probe of p from h (metrics/probe.py) and the local-PCA dimension of h
over the positions (metrics/dimension.py: TwoNN diverges on a lattice such as the grid's sampling),
all on the regular sampling, and the wall time the run took."""

from __future__ import annotations

from typing import Any

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.metrics import spatial_scores
from smspace.metrics.dimension import local_pca_dimension
from smspace.metrics.probe import probe_r2
from smspace.metrics.spatial import DegenerateRepresentation, check_representation
from smspace.train.run_dir import RunView

SCORES = ("d_topo", "d_metric", "probe_r2", "local_dim")
LOWER_IS_BETTER = {"d_topo": True, "d_metric": True, "probe_r2": False, "local_dim": None}  # None: 2 is the plane


def scores_of(h: np.ndarray, p: np.ndarray, seed: int) -> dict[str, float]:
    """Every score of an h of the regular states; `seed`: the world's (the probe's folds). A
    degenerate h (non-finite, collapsed) is refused, never scored."""
    spatial = spatial_scores(h, p)
    return {"d_topo": spatial.d_topo, "d_metric": spatial.d_metric, **beyond_the_paper(h, p, seed)}


def beyond_the_paper(h: np.ndarray, p: np.ndarray, seed: int) -> dict[str, float]:
    check_representation(h)
    try:
        dimension = local_pca_dimension(mean_per_position(h, p))
    except ValueError as e:  # h averaged per position collapsed to fewer than 3 points
        raise DegenerateRepresentation(f"h averaged over each position collapsed ({e})") from None
    return {"probe_r2": probe_r2(h, p, seed=seed), "local_dim": dimension}


def mean_per_position(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    """h averaged over the states that share a position: the surface h traces as the sensor
    moves. Redundant motors put many states at one position (5 in the grid, 625 in grid6): their
    h, close but not equal, would make every neighbourhood a cluster and the dimension that of
    its spread (how far h is from a function of p is D_topo's to say)."""
    _, group = np.unique(np.asarray(p), axis=0, return_inverse=True)
    group = group.ravel()
    sums = np.zeros((group.max() + 1, h.shape[1]))
    np.add.at(sums, group, np.asarray(h, np.float64))
    return sums / np.bincount(group)[:, None]


def world_and_mode(dataset_id: str) -> tuple[int, str]:
    """setup-seedW-MODE -> (W, MODE)."""
    head, mode = dataset_id.rsplit("-", 1)
    return int(head.rsplit("-seed", 1)[1]), mode


def run_scores(run: RunView, steps: int) -> tuple[dict[str, Any], np.ndarray]:
    """A trained run's row (its world, mode, step and wall time) and the h its scores are computed
    from: that of its last evaluation, which must be the task's last step."""
    rows = run.metrics()
    last = rows[-1]
    if last["step"] != steps:
        raise SmspaceError(f"{run.name} ended at step {last['step']}, not the task's {steps}")
    h, _ = run.embeddings(last["step"])
    world, mode = world_and_mode(run.config.dataset_id)
    return {"world": world, "mode": mode, "step": last["step"], "wall_s": last["elapsed_s"], "run": run.name}, h
