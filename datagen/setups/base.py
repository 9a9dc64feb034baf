"""What a setup is (docs/MODEL.md §2): a world to build from a seed, its numbers, and its hooks
for previews and viewers. Each setup's module declares its own; the registry only collects them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from smspace.lake.transitions import Transitions


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
    """Draw n transitions; the mode only decides how the shifts are drawn (docs/MODEL.md §1)."""
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


def _nothing() -> None:
    return None


@dataclass(frozen=True)
class Setup:
    name: str
    n_motor: int
    description: str
    build: Callable[[int], World]
    encoder_layers: tuple[int, ...]  # the paper's Net_enc hidden sizes for this body
    shift_bound: float  # |shift component| ≤ shift_bound (the MM shift may sit outside: it is fixed)
    default_transitions: int = 150_000
    default_shard_size: int = 32768  # transitions per shard: arm shards are smaller so workers stay balanced
    default_walk_step: float = 1.0  # a walk's step (datagen/walks.py) in this body's motor units
    bytes_per_transition: int = 16  # an upper estimate of the zstd shards (measured: grid 15, arm 554), for disk checks
    preflight: Callable[[], None] = _nothing  # fails early (before anything is written) if unusable
    # versions beyond the libraries' that shape the bytes (a renderer, its driver and device)
    provenance: Callable[[], dict[str, str]] = dict
    # Pictures of the world itself for `smgen preview`: (world, folder) → files written.
    preview: Callable[[Any, Path], list[Path]] | None = None
    # Extra panels for `smgen view`: (recording, world, transitions, time columns); None: none.
    view_world: Callable[[Any, Any, Transitions, list], None] | None = None
