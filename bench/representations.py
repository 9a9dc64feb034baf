"""Entries that learn nothing: a representation computed from a dataset, scored as a trained
run's h is. `isomap`, in the spirit of Philipona and O'Regan: how far the sensory manifold alone
goes. For each regular motor state, the sensation of the transition whose m_t is nearest (exactly
the state's own sensation where the world stands still, MM; a sensation of some shifted world in
MEM and MME, where nothing but the motor state fixes what is seen); then Isomap of those
sensations to N_h dimensions (scikit-learn), fitted on at most LANDMARKS states drawn from the
task's seed, the others placed by its out-of-sample map.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers

LANDMARKS = 2000  # Isomap's geodesics are a dense LANDMARKS² matrix: 32 MB
NEIGHBOURS = 10

Representation = Callable[[Dataset, int, int], np.ndarray]  # (dataset, n_h, seed) -> h of the regular states


def isomap_of_sensations(ds: Dataset, n_h: int, seed: int) -> np.ndarray:
    from sklearn.manifold import Isomap
    from sklearn.neighbors import NearestNeighbors

    m_norm, s_norm = normalisers(ds.manifest)
    m_reg, _ = ds.regular_sampling()
    seen = ds.read_all()
    index = NearestNeighbors(n_neighbors=1).fit(m_norm(seen.m_t))
    nearest = index.kneighbors(m_norm(m_reg), return_distance=False)[:, 0]
    s = s_norm(seen.s_t[nearest]).reshape(len(m_reg), -1).astype(np.float64)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(11,)))
    fit_on = np.sort(rng.choice(len(s), min(LANDMARKS, len(s)), replace=False))
    with warnings.catch_warnings():  # a graph in several components (alike sensations far apart) is joined
        warnings.simplefilter("ignore")  # by scikit-learn, which says so on every call
        isomap = Isomap(  # a dense eigensolver: ARPACK starts from a random vector, differing in the last digits
            n_neighbors=min(NEIGHBOURS, len(fit_on) - 1), n_components=n_h, eigen_solver="dense"
        ).fit(s[fit_on])
        return isomap.transform(s)


REPRESENTATIONS: dict[str, Representation] = {"isomap": isomap_of_sensations}
