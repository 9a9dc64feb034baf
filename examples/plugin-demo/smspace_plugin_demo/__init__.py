"""A setup and a network for smspace, registered through entry points (see pyproject.toml)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from smspace.datagen.setups.base import Setup

CELLS = 20
LEVELS = np.linspace(0.0, 1.0, 11)


class LineWorld:
    """A sensor on a ring of CELLS cells; two motors, whose mean sets its position (so several motor
    states see one position); the ring itself is what shifts move."""

    n_motor = 2
    sensor_shape = (3,)
    sensor_dtype = np.dtype(np.float32)
    static_shift = np.zeros(2)

    def __init__(self, seed: int):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))
        x = np.arange(CELLS) / CELLS
        freq, phase, amp = rng.integers(1, 4, (3, 3)), rng.uniform(0, 1, (3, 3)), rng.uniform(0.3, 1.0, (3, 3))
        self.table = np.stack(
            [sum(amp[i, k] * np.cos(2 * np.pi * (freq[i, k] * x + phase[i, k])) for k in range(3)) for i in range(3)],
            axis=1,
        ).astype(np.float32)
        u = np.array([(a, b) for a in LEVELS for b in LEVELS])
        self.motors = 2 * u - 1
        self.positions = np.stack([np.rint(10 * u.mean(axis=1)) - 5, np.zeros(len(u))], axis=1)

    def sample_motors(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        idx = rng.integers(0, len(self.motors), n)
        return self.motors[idx], self.positions[idx]

    def sample_shifts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return np.stack([rng.integers(-10, 10, n), np.zeros(n)], axis=1).astype(np.float64)

    def sense(self, p: np.ndarray, shift: np.ndarray) -> np.ndarray:
        cell = np.mod(np.rint(p[:, 0] + shift[:, 0]).astype(np.int64), CELLS)
        return self.table[cell]

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        return self.motors, self.positions


LINE = Setup(
    "line",
    n_motor=2,
    description="a sensor on a ring of 20 cells moved by 2 motors (examples/plugin-demo)",
    build=LineWorld,
    encoder_layers=(32, 16),
    shift_bound=10.0,
    default_transitions=20_000,
)


class ShallowNet(nn.Module):
    """h = W m + b (no hidden layer); s_t1 predicted from (h_t, h_t1, s_t) through one hidden layer."""

    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers, width: int = 64):
        super().__init__()
        self.encoder = nn.Linear(n_motor, n_h)
        self.predictor = nn.Sequential(nn.Linear(2 * n_h + n_sensor, width), nn.SELU(), nn.Linear(width, n_sensor))

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return self.predictor(torch.cat([self.encode(m_t), self.encode(m_t1), s_t], dim=-1))
