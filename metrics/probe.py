"""How linearly h encodes position, on states the map never saw: a held-out linear probe.

D_metric fits the affine map from h to p and scores it on the same states (docs/MODEL.md §4), so
enough directions in h fit any set of positions. The probe fits on K-1 folds of the regular
sampling and predicts the fold left out, each fold once (folds drawn from a recorded seed); R²
pools the held-out residuals of every fold and component: 1 − SSE / SST, SST about p's mean.
"""

from __future__ import annotations

import numpy as np

from smspace.metrics.spatial import RANK_TOLERANCE

FOLDS = 5


def probe_r2(h: np.ndarray, p: np.ndarray, folds: int = FOLDS, seed: int = 0) -> float:
    """Held-out R² of p predicted from h by an affine map: 1 exact, 0 no better than p's mean,
    below 0 worse than it."""
    h, p = np.asarray(h, np.float64), np.asarray(p, np.float64)
    n = len(h)
    if n < 2 * folds or len(p) != n:
        raise ValueError(f"need at least {2 * folds} samples with one position each (got {n} h, {len(p)} p)")
    sst = float(((p - p.mean(axis=0)) ** 2).sum())
    if sst == 0:
        raise ValueError("all positions coincide: R² is undefined")
    order = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,))).permutation(n)
    sse = 0.0
    for k in range(folds):
        held = np.zeros(n, bool)
        held[order[k::folds]] = True
        predicted = affine_map(h[~held], p[~held], h[held])
        sse += float(((predicted - p[held]) ** 2).sum())
    return 1.0 - sse / sst


def affine_map(h_fit: np.ndarray, p_fit: np.ndarray, h_new: np.ndarray) -> np.ndarray:
    """p of `h_new` by the affine least-squares map fitted on (h_fit, p_fit), conditioned as
    D_metric's fit is (h standardised, directions below RANK_TOLERANCE left out)."""
    spread = h_fit.std(axis=0)
    keep = spread > 0
    mean = h_fit.mean(axis=0)

    def design(h: np.ndarray) -> np.ndarray:
        return np.hstack([(h[:, keep] - mean[keep]) / spread[keep], np.ones((len(h), 1))])

    coef, *_ = np.linalg.lstsq(design(h_fit), p_fit, rcond=RANK_TOLERANCE)
    return design(h_new) @ coef


def on_the_torus(p: np.ndarray, period: float) -> np.ndarray:
    """Each coordinate of p as the angle it makes on a circle of circumference `period`, (cos, sin):
    p modulo the period, which a representation of a world that repeats every `period` may encode
    instead of p itself."""
    angle = 2 * np.pi * np.asarray(p, np.float64) / period
    return np.hstack([np.cos(angle), np.sin(angle)])


def torus_probe_r2(h: np.ndarray, p: np.ndarray, period: float, folds: int = FOLDS, seed: int = 0) -> float:
    """Held-out R² of p modulo `period` (on_the_torus) predicted from h by an affine map: whether h
    learned the torus a periodic world allows, where probe_r2 asks for the plane."""
    if not period > 0:
        raise ValueError(f"a period is > 0, not {period}")
    return probe_r2(h, on_the_torus(p, period), folds, seed)
