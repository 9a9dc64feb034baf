"""The hand-written ensemble smspace used before its ensembles became torch.func (kept only as the
benchmark's reference): weights (R, in, out), biases (R, 1, out), one baddbmm per layer."""

from __future__ import annotations

import itertools

import torch
from torch import nn


class EnsembleMLP(nn.Module):
    def __init__(self, runs: int, sizes: list[int]):
        super().__init__()
        self.weights = nn.ParameterList(nn.Parameter(torch.empty(runs, a, b)) for a, b in itertools.pairwise(sizes))
        self.biases = nn.ParameterList(nn.Parameter(torch.zeros(runs, 1, b)) for b in sizes[1:])
        for w in self.weights:
            for r in range(runs):
                nn.init.xavier_uniform_(w.data[r])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = torch.baddbmm(b, x, w)
            if i < last:
                x = torch.selu(x)
        return x


class EnsembleNet(nn.Module):
    def __init__(self, runs: int, n_motor: int, n_sensor: int, n_h: int, encoder: list[int], predictor: list[int]):
        super().__init__()
        self.encoder = EnsembleMLP(runs, [n_motor, *encoder, n_h])
        self.predictor = EnsembleMLP(runs, [2 * n_h + n_sensor, *predictor, n_sensor])

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        b = m_t.shape[1]
        h = self.encoder(torch.cat([m_t, m_t1], dim=1))
        return self.predictor(torch.cat([h[:, :b], h[:, b:], s_t], dim=2))
