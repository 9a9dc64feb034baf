"""What every agent/world setup provides to the generator (SPEC 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

MODES = ("MEM", "MM", "MME")


@dataclass(frozen=True)
class Transitions:
    """A block of i.i.d. transitions, with privileged ground truth alongside."""

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


class World(Protocol):
    """One world (sensory environment + agent body) built from a seed; shared by its modes."""

    n_motor: int
    sensor_shape: tuple[int, ...]
    sensor_dtype: np.dtype
    static_shift: np.ndarray  # the MM shift, (2,)

    def sample_motors(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Random motor states (n, N_m) in [-1, 1] with their egocentric positions (n, 2)."""
        ...

    def sample_shifts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Random environment shifts (n, 2)."""
        ...

    def sense(self, p: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """Sensory states seen at egocentric position p with the environment shifted by shift."""
        ...

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        """The fixed evaluation motor states and their positions."""
        ...


def draw_transitions(world: World, mode: str, rng: np.random.Generator, n: int) -> Transitions:
    """Draw n transitions; the mode only decides how the shifts are drawn (SPEC 1)."""
    m_t, p_t = world.sample_motors(rng, n)
    m_t1, p_t1 = world.sample_motors(rng, n)
    if mode == "MM":
        shift_t = np.broadcast_to(world.static_shift, (n, 2))
        shift_t1 = shift_t
    elif mode == "MME":
        shift_t = world.sample_shifts(rng, n)
        shift_t1 = shift_t
    elif mode == "MEM":
        shift_t = world.sample_shifts(rng, n)
        shift_t1 = world.sample_shifts(rng, n)
    else:
        raise ValueError(f"unknown mode {mode!r}")
    f32 = np.float32
    return Transitions(
        m_t=m_t.astype(f32),
        m_t1=m_t1.astype(f32),
        s_t=world.sense(p_t, shift_t),
        s_t1=world.sense(p_t1, shift_t1),
        p_t=p_t.astype(f32),
        p_t1=p_t1.astype(f32),
        shift_t=np.ascontiguousarray(shift_t, dtype=f32),
        shift_t1=np.ascontiguousarray(shift_t1, dtype=f32),
    )
