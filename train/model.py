"""The sensorimotor predictive network (docs/MODEL.md §3): a siamese motor encoder and a sensory predictor."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch
from torch import nn


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Linear layers with SELU between them and a linear output; Glorot-uniform weights, zero biases."""
    layers: list[nn.Module] = []
    for i, (fan_in, fan_out) in enumerate(itertools.pairwise(sizes)):
        linear = nn.Linear(fan_in, fan_out)
        nn.init.xavier_uniform_(linear.weight)  # TF1 dense default, not PyTorch's Kaiming
        nn.init.zeros_(linear.bias)
        layers.append(linear)
        if i < len(sizes) - 2:
            layers.append(nn.SELU())
    return nn.Sequential(*layers)


class SensorimotorNet(nn.Module):
    """Net_enc: m → h (shared by m_t and m_t1); Net_pred: (h_t, h_t1, s_t) → s_t1."""

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
    ):
        super().__init__()
        self.encoder = mlp([n_motor, *encoder_layers, n_h])
        self.predictor = mlp([2 * n_h + n_sensor, *predictor_layers, n_sensor])

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        # one encoder call on both halves: the same weights, half the per-call overhead
        h = self.encoder(torch.cat([m_t, m_t1]))
        h_t, h_t1 = h[: len(m_t)], h[len(m_t) :]
        return self.predictor(torch.cat([h_t, h_t1, s_t], dim=1))


def prediction_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared error summed over sensor components, averaged over the batch (not mse_loss)."""
    return (pred - target).pow(2).sum(dim=1).mean()
