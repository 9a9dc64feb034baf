"""The column container every reader and writer of the lake passes around."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

MODES = ("MEM", "MM", "MME")  # how a dataset's shifts were drawn (docs/MODEL.md §1)


@dataclass(frozen=True)
class Transitions:
    """A block of i.i.d. transitions, with the privileged ground truth (p, shift) alongside."""

    m_t: np.ndarray  # (n, N_m) float32
    m_t1: np.ndarray
    s_t: np.ndarray  # (n, *sensor_shape), float32 or uint8
    s_t1: np.ndarray
    p_t: np.ndarray  # (n, 2) float32
    p_t1: np.ndarray
    shift_t: np.ndarray  # (n, 2) float32
    shift_t1: np.ndarray

    def __len__(self) -> int:
        return len(self.m_t)

    def columns(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in COLUMNS}

    def __getitem__(self, rows: slice) -> Transitions:
        return Transitions(**{name: col[rows] for name, col in self.columns().items()})

    @classmethod
    def concat(cls, parts: Sequence[Transitions]) -> Transitions:
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in COLUMNS})


COLUMNS: tuple[str, ...] = tuple(f.name for f in fields(Transitions))
