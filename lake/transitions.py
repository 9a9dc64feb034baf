"""The column container every reader and writer of the lake passes around."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from smspace.common.errors import SmspaceError

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


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise SmspaceError(f"unknown mode {mode!r} (choose from {', '.join(MODES)} or all)")
    return mode


def parse_modes(text: str) -> list[str]:
    """--mode / --modes: one mode, several separated by commas, or all."""
    names = [m.strip() for m in text.split(",")]
    if names == ["all"]:
        return list(MODES)
    if "" in names:
        raise SmspaceError(f"--modes {text!r} has an empty entry (give e.g. MEM,MM or all)")
    modes = [check_mode(m) for m in names]
    if len(set(modes)) != len(modes):
        raise SmspaceError(f"--modes {text!r} names a mode twice")
    return modes
