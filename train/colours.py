"""One colour per sensor position p, shared by `smtrain report`'s figures and `smtrain view`'s
replay, so that a point has the same colour in both: red grows with p_x, blue with p_y (as in the
paper's figure), and neighbours in space have neighbouring colours."""

from __future__ import annotations

import numpy as np


def position_colours(p: np.ndarray) -> np.ndarray:
    """RGB in [0, 1], one row per position."""
    lo, hi = p.min(0), p.max(0)
    u = (p - lo) / np.where(hi > lo, hi - lo, 1.0)
    x, y = u[:, 0], u[:, 1] if p.shape[1] > 1 else np.zeros(len(p))
    return np.clip(np.stack([0.15 + 0.8 * x, 0.35 + 0.3 * (1 - np.abs(x - y)), 0.15 + 0.8 * y], 1), 0, 1)


def position_colours_u8(p: np.ndarray) -> np.ndarray:
    """The same colours as 8-bit RGB, for rerun."""
    return np.round(255 * position_colours(p)).astype(np.uint8)
