"""Every score of a representation, declared once (as lm-eval's registry declares a metric): its
name, its title, which way is better, the values it can take, and how it is computed from h of
the regular states, their positions p and the world's seed. The bench, its verification, the
leaderboard and the report read this table; a new score is one entry here."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from smspace.metrics.dimension import local_pca_dimension
from smspace.metrics.probe import probe_r2
from smspace.metrics.spatial import DegenerateRepresentation, check_representation, spatial_scores


@dataclass(frozen=True)
class Score:
    name: str  # the key in records: scores.json, metrics.jsonl
    title: str  # what it measures, for tables and figures
    better: Literal["lower", "higher"] | None  # None: no direction (local_dim: 2 is the plane)
    low: float
    high: float | None  # None: at most N_h
    compute: Callable[[np.ndarray, np.ndarray, int], float]  # (h, p, world seed) -> value

    @property
    def arrow(self) -> str:
        return {"lower": "↓", "higher": "↑", None: ""}[self.better]

    @property
    def heading(self) -> str:
        """The title with its direction, as a table's section says it."""
        return f"{self.title} {self.arrow} ({self.better}: better)" if self.better else self.title

    def can_take(self, value: object, n_h: int) -> bool:
        """Whether `value` is a number this score can take for an h of N_h dimensions."""
        if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
            return False
        return self.low <= value <= (n_h if self.high is None else self.high)


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


def _local_dim(h: np.ndarray, p: np.ndarray, seed: int) -> float:
    check_representation(h)
    try:
        return local_pca_dimension(mean_per_position(h, p))
    except ValueError as e:  # h averaged per position collapsed to fewer than 3 points
        raise DegenerateRepresentation(f"h averaged over each position collapsed ({e})") from None


def _probe(h: np.ndarray, p: np.ndarray, seed: int) -> float:
    check_representation(h)
    return probe_r2(h, p, seed=seed)


SCORES: dict[str, Score] = {
    s.name: s
    for s in (
        Score("d_topo", "D_topo", "lower", 0.0, 1.0, lambda h, p, seed: spatial_scores(h, p).d_topo),
        Score("d_metric", "D_metric", "lower", 0.0, math.inf, lambda h, p, seed: spatial_scores(h, p).d_metric),
        Score("probe_r2", "held-out probe R² of p from h", "higher", -math.inf, 1.0, _probe),
        Score("local_dim", "local-PCA dimension of h", None, 1.0, None, _local_dim),
    )
}


def scores_of(h: np.ndarray, p: np.ndarray, seed: int) -> dict[str, float]:
    """Every score of an h of the regular states; `seed`: the world's (the probe's folds). A
    degenerate h (non-finite, collapsed) is refused, never scored."""
    spatial = spatial_scores(h, p)  # D_topo and D_metric come from one pass: computed once
    paper = {"d_topo": spatial.d_topo, "d_metric": spatial.d_metric}
    return {name: paper[name] if name in paper else score.compute(h, p, seed) for name, score in SCORES.items()}
