"""The discrete torus worlds of docs/MODEL.md §2.1 (`grid`, 3 motors) and §2.2 (`grid6`, 6 motors)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from smspace.datagen.setups.base import Setup
from smspace.datagen.walks import lattice_walk

GRID_SIZE = 10
LEVELS = np.linspace(0.0, 1.0, 5)  # u ∈ {0, .25, .5, .75, 1}
SHIFT_LOW, SHIFT_HIGH = -10, 9  # integer shifts, both ends included
STATIC_SHIFT = np.array([5.0, 5.0])


def sensory_table(rng: np.random.Generator, n_sensors: int = 4, size: int = GRID_SIZE) -> np.ndarray:
    """S[r, c, i] (size × size × n_sensors), each component a sum of six random cosines (docs/MODEL.md §2.1)."""
    c, r = np.meshgrid(np.arange(size), np.arange(size))
    x, y = c / size, r / size
    table = np.empty((size, size, n_sensors))
    for i in range(n_sensors):
        lam = rng.uniform(-2.0, 2.0, 12)
        amp = lam[0::2]
        lam[0::2] = np.where(amp < 0, -1.0, 1.0) * np.maximum(np.abs(amp), 0.25)
        s = np.zeros((size, size))
        for k, coord in ((0, x), (2, x), (4, x), (6, y), (8, y), (10, y)):
            s += np.cos(2 * np.pi * (np.round(lam[k]) * coord + lam[k + 1])) / lam[k]
        table[:, :, i] = s
    return table


def level_grid(n_dims: int) -> np.ndarray:
    """All 5**n_dims states u of the discrete motor space, first component slowest."""
    return np.array(list(itertools.product(LEVELS, repeat=n_dims)))


def _six_motor_nonlinearities(x: np.ndarray) -> np.ndarray:
    """Per-column maps of [0, 1] onto itself (docs/MODEL.md §2.2), inverse of the paper's f."""
    log_map = (np.log((x[:, 3] + 0.1) / 1.1) - np.log(0.1 / 1.1)) / (-np.log(0.1 / 1.1))
    return np.stack(
        [np.sqrt(x[:, 0]), x[:, 1] ** 2, x[:, 2] ** 3, log_map, (np.exp(x[:, 4]) - 1) / (np.e - 1), x[:, 5]],
        axis=1,
    )


class GridWorld:
    """A 10×10 torus of sensations explored by a discrete agent; `n_motor` is 3 or 6."""

    static_shift = STATIC_SHIFT
    sensor_dtype = np.dtype(np.float32)

    def __init__(self, world_seed: int, n_motor: int = 3):
        if n_motor not in (3, 6):
            raise ValueError(f"grid worlds have 3 or 6 motors, not {n_motor}")
        rng = np.random.default_rng(np.random.SeedSequence(world_seed, spawn_key=(0,)))
        self.n_motor = n_motor
        self.table = sensory_table(rng)
        self.sensor_shape = (self.table.shape[2],)
        u = level_grid(n_motor)
        if n_motor == 3:
            self.motors = 2 * u**3 - 1
            self.positions = np.rint(4 * u[:, :2] - 2)
        else:
            mixing = rng.uniform(-2.0, 2.0, (6, 6))
            v = u @ np.linalg.inv(mixing)
            v = (v - v.min(axis=0)) / (v.max(axis=0) - v.min(axis=0))
            self.motors = 2 * _six_motor_nonlinearities(v) - 1
            self.positions = np.trunc(4 * (u[:, :2] - 0.5))

    def sample_motors(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        idx = rng.integers(0, len(self.motors), n)
        return self.motors[idx], self.positions[idx]

    def walk_motors(
        self, rng: np.random.Generator, episodes: int, length: int, step: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Walks on the lattice of motor levels (datagen/walks.py): each motor moves by at most
        `step` levels per step."""
        whole = int(step) if float(step).is_integer() else step  # a config records it as a number
        idx = lattice_walk(rng, self.n_motor, len(LEVELS), episodes, length, whole)
        return self.motors[idx], self.positions[idx]

    def sample_shifts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.integers(SHIFT_LOW, SHIFT_HIGH + 1, size=(n, 2)).astype(np.float64)

    def sense(self, p: np.ndarray, shift: np.ndarray) -> np.ndarray:
        cell = np.mod(np.rint(p + shift).astype(np.int64), GRID_SIZE)
        return self.table[cell[:, 0], cell[:, 1]].astype(np.float32)

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        return self.motors, self.positions


def sensory_table_image(table: np.ndarray, scale: int = 24):
    """The world's S[r, c, i] as one grey panel per component (black = min, white = max)."""
    from PIL import Image

    panels = []
    for i in range(table.shape[2]):
        t = table[:, :, i]
        g = np.round(255 * (t - t.min()) / max(t.max() - t.min(), 1e-12)).astype(np.uint8)
        panel = np.pad(g.repeat(scale, 0).repeat(scale, 1), 4, constant_values=255)
        panels.append(np.repeat(panel[..., None], 3, axis=2))
    return Image.fromarray(np.concatenate(panels, axis=1))


def write_preview(world: GridWorld, out: Path) -> list[Path]:
    path = out / "sensory_table.png"
    sensory_table_image(world.table).save(path)
    return [path]


def _builder(n_motor: int):
    def build(seed: int) -> GridWorld:
        return GridWorld(seed, n_motor)

    return build


SETUPS = (
    Setup(
        "grid",
        n_motor=3,
        description="10×10 torus, 3 motors, 4 sensors (docs/MODEL.md §2.1)",
        build=_builder(3),
        encoder_layers=(150, 100, 50),
        shift_bound=float(max(-SHIFT_LOW, SHIFT_HIGH)),
        preview=write_preview,
    ),
    Setup(
        "grid6",
        n_motor=6,
        description="10×10 torus, 6 mixed motors (docs/MODEL.md §2.2)",
        build=_builder(6),
        encoder_layers=(500, 400, 300, 200),
        shift_bound=float(max(-SHIFT_LOW, SHIFT_HIGH)),
        bytes_per_transition=64,
        preview=write_preview,
    ),
)
