"""Per-component scaling to [-1, 1] with a dataset's recorded min/max (docs/MODEL.md §2.5).

It lives with the lake because the statistics are the manifest's: every reader (the training
loader, the viewers, a third party) must scale exactly the same way and be able to undo it.
"""

from __future__ import annotations

import numpy as np

from smspace.lake.manifest import Manifest


class Normaliser:
    """2(x − min)/(max − min) − 1 per component; a component with max = min maps to 0."""

    def __init__(self, lo: list[float], hi: list[float]):
        lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        span = hi_a - lo_a
        safe = np.where(span > 0, span, 1.0)
        self.lo, self.hi = lo_a, hi_a
        self.scale = np.where(span > 0, 2.0 / safe, 0.0).astype(np.float32)
        self.offset = np.where(span > 0, -2.0 * lo_a / safe - 1.0, 0.0).astype(np.float32)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(n, ...) raw values → (n, components) float32 in [-1, 1]."""
        flat = x.reshape(len(x), -1).astype(np.float32)
        return flat * self.scale + self.offset

    def inverse(self, y: np.ndarray) -> np.ndarray:
        """Normalised values back to raw units (float64); constant components come back as their value."""
        return (np.asarray(y, np.float64) + 1.0) / 2.0 * (self.hi - self.lo) + self.lo


def normalisers(manifest: Manifest) -> tuple[Normaliser, Normaliser]:
    """(motor, sensor) normalisers of a dataset."""
    n = manifest.normalisation
    return Normaliser(n["m_min"], n["m_max"]), Normaliser(n["s_min"], n["s_max"])
