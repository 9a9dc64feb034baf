"""The displacement score: how much of the structure of the sensor's *moves* a representation of
motor changes captured (Garcia Ortiz & Laflaquière 2018).

A displacement model encodes a pair of motor states, d(m_a → m_b), not a posture. Its score is the
paper's pair of metrics applied to moves instead of places: D_topo and D_metric (metrics/spatial.py)
of the d of sampled pairs against the sensor's displacements p_b − p_a. Two pairs that move the
sensor alike, from wherever they start, should get near d; a d that only encodes where the move ends
(d(0 → m) is all the posture score sees) scores badly once the starts differ. The pairs are drawn
from a recorded seed over the regular states, a ≠ b, so the same seed gives the same pairs.
"""

from __future__ import annotations

import numpy as np

from smspace.metrics.spatial import SpatialScores, spatial_scores

PAIRS = 2000  # enough moves for a spread of starts and ends; D over 2e6 pair-of-pairs terms


def displacement_pairs(states: int, pairs: int = PAIRS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Indices (a, b) of `pairs` moves between distinct regular states, from `seed` alone."""
    if states < 2:
        raise ValueError(f"need at least two states to move between (got {states})")
    if pairs < 2:
        raise ValueError(f"need at least two pairs (got {pairs})")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(11,)))
    a = rng.integers(0, states, pairs)
    b = (a + rng.integers(1, states, pairs)) % states  # uniform over the other states
    return a, b


def displacement_scores(d: np.ndarray, p: np.ndarray, a: np.ndarray, b: np.ndarray) -> SpatialScores:
    """D_topo and D_metric of the moves' representations d (pairs, N_h) against p[b] − p[a]."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or len(a) != len(d):
        raise ValueError(f"{len(d)} displacement representations for {len(a)} starts and {len(b)} ends")
    p = np.asarray(p, np.float64)
    return spatial_scores(d, p[b] - p[a])
