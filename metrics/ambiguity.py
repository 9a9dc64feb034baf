"""How ambiguous a world's views are: do sensor positions far apart see images as alike as
neighbours? (The paper's explanation of the arm's MM topology, made measurable.)

For each view, its K most similar views by pixel distance: how far away were they taken?
`lookalike_distance` is the mean camera distance to those K look-alikes (small: similar views come
from nearby; large: the world repeats); `far_lookalikes` the share of views with a look-alike more
than FAR away. `image_geometry_*` score an Isomap of image similarity with D_topo and D_metric:
what a representation that only followed image similarity would achieve.
"""

from __future__ import annotations

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.metrics.spatial import spatial_scores

K, FAR = 5, 0.5  # image neighbours per view; a camera distance that is not a neighbour (room units)
GRAPH_K = 8  # neighbours per view in the graph of image similarity


def ranks(x: np.ndarray) -> np.ndarray:
    """Ranks with ties averaged (Spearman's convention)."""
    order = np.empty(len(x))
    order[np.argsort(x, kind="stable")] = np.arange(len(x))
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    return (np.bincount(inverse, weights=order) / counts)[inverse]


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(ranks(a), ranks(b))[0, 1])


def pairwise(x: np.ndarray) -> np.ndarray:
    sq = (x * x).sum(1)
    return np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2 * x @ x.T, 0))


def view_ambiguity(p: np.ndarray, s: np.ndarray) -> dict[str, float]:
    """For each view, its K most similar views (pixel distance): how far away were they taken?
    far_lookalikes: the share of views with a look-alike more than FAR away (0 when every view is
    distinctive); lookalike_distance: the mean camera distance to the K look-alikes."""
    d_s = pairwise(s.reshape(len(s), -1).astype(np.float64))
    np.fill_diagonal(d_s, np.inf)
    nearest = np.argsort(d_s, axis=1)[:, :K]
    d_p = np.linalg.norm(p[nearest] - p[:, None, :], axis=2)
    geometry = spatial_scores(isomap(d_s, GRAPH_K, 3), p)
    return {
        "far_lookalikes": float((d_p.max(1) > FAR).mean()),
        "lookalike_distance": float(d_p.mean()),
        "image_geometry_d_topo": geometry.d_topo,
        "image_geometry_d_metric": geometry.d_metric,
    }


def isomap(d: np.ndarray, k: int, dims: int) -> np.ndarray:
    """Points whose distances follow the geodesics of the k-nearest-neighbour graph of `d` (the
    shape a representation that only follows image similarity would take)."""
    n = len(d)
    graph = np.full((n, n), np.inf)
    nearest = np.argsort(d, axis=1)[:, :k]
    rows = np.repeat(np.arange(n), k)
    graph[rows, nearest.ravel()] = d[rows, nearest.ravel()]
    graph = np.minimum(graph, graph.T)
    np.fill_diagonal(graph, 0)
    for via in range(n):  # Floyd-Warshall, one row-column sweep at a time
        np.minimum(graph, graph[:, via, None] + graph[None, via, :], out=graph)
    if not np.isfinite(graph).all():
        raise SmspaceError(f"the {k}-nearest-neighbour graph of the views is not connected: use more views")
    centred = -0.5 * (np.eye(n) - 1 / n) @ (graph**2) @ (np.eye(n) - 1 / n)
    values, vectors = np.linalg.eigh(centred)
    top = np.argsort(values)[::-1][:dims]
    return vectors[:, top] * np.sqrt(np.maximum(values[top], 0))
