"""The intrinsic dimension of h over the regular sampling: TwoNN (Facco et al., Scientific Reports
2017). For each point, μ = r₂ / r₁, the ratios of its second to its first nearest-neighbour
distance, follow a Pareto law whose exponent is the dimension d of the manifold the points lie
on, whatever the dimension they are embedded in: d = (N − 1) / Σ log μ (maximum likelihood,
unbiased). A representation of the plane's positions has d ≈ 2 whatever N_h is.

Points that coincide (several motor states with one h) have r₁ = 0 and say nothing of the
manifold: duplicates are merged first. Distances in float64, in blocks of rows.
"""

from __future__ import annotations

import numpy as np

BLOCK_ROWS = 256  # rows of squared distances at once: 256 x 15625 float64 = 32 MB
LOCAL_K = 10  # neighbours of a point in local PCA: a lattice's 8 around it, and two more
LOCAL_SHARE = 0.9  # of a neighbourhood's spread that its dimensions must explain


def two_nn_dimension(h: np.ndarray) -> float:
    """TwoNN's estimate of the dimension of the manifold the rows of h lie on."""
    x = np.unique(np.asarray(h, np.float64), axis=0)
    n = len(x)
    if n < 3:
        raise ValueError(f"need at least 3 distinct points (got {n})")
    log_mu = np.empty(n)
    for a in range(0, n, BLOCK_ROWS):
        b = min(a + BLOCK_ROWS, n)
        d2 = np.zeros((b - a, n))
        for k in range(x.shape[1]):  # differences, not the Gram form: near neighbours stay exact
            diff = x[a:b, k, None] - x[None, :, k]
            d2 += diff * diff
        d2[np.arange(b - a), np.arange(a, b)] = np.inf  # a point is not its own neighbour
        two = np.sqrt(np.partition(d2, 1, axis=1)[:, :2])
        log_mu[a:b] = np.log(two[:, 1] / two[:, 0])
    total = float(log_mu.sum())
    return float("inf") if total == 0 else (n - 1) / total


def local_pca_dimension(h: np.ndarray, k: int = LOCAL_K, share: float = LOCAL_SHARE) -> float:
    """The dimension of the manifold the rows of h lie on, from the principal components of each
    point's k nearest neighbours: how many explain `share` of their spread, averaged over the points
    (Fukunaga and Olsen's local PCA). Unlike TwoNN it holds on a regular sampling: on a lattice a
    point's first and second neighbours are equally far, r₂ / r₁ = 1, and TwoNN diverges (it gives
    inf for the grid world's 5×5 positions), while their neighbourhoods still span the lattice's
    dimensions. Duplicates are merged first, as in `two_nn_dimension`."""
    x = np.unique(np.asarray(h, np.float64), axis=0)
    n = len(x)
    if n < 3:
        raise ValueError(f"need at least 3 distinct points (got {n})")
    k = min(k, n - 1)
    dims = np.empty(n)
    for a in range(0, n, BLOCK_ROWS):
        b = min(a + BLOCK_ROWS, n)
        d2 = np.zeros((b - a, n))
        for c in range(x.shape[1]):
            diff = x[a:b, c, None] - x[None, :, c]
            d2 += diff * diff
        nearest = np.argpartition(d2, k, axis=1)[:, : k + 1]  # itself (distance 0) and its k neighbours
        for i, rows in enumerate(nearest):
            local = x[rows] - x[rows].mean(axis=0)
            spread = np.linalg.svd(local, compute_uv=False) ** 2
            dims[a + i] = 1 + int(np.searchsorted(np.cumsum(spread) / spread.sum(), share - 1e-12))
    return float(dims.mean())
