"""The benchmark's learned baselines, registered as models through smspace's own entry points
(pyproject.toml, `smspace.models`) exactly as a researcher's package registers theirs: each is
recorded by its code hash, checked by the same contract and trained by the same engine.

Beside the paper's network (`sensorimotor`), they bracket what it learns:
- `random-encoder`, the floor: the paper's network whose encoder keeps the random weights its
  seed draws; only the predictor learns. Whatever structure h shows, a random map of m has.
- `motor-autoencoder`, the control: m -> h -> m, never shown a sensation. Structure it shows comes
  from the motor states' own statistics, not from sensorimotor experience.
- `contrastive`, another objective on the paper's inputs: (h_t, h_t1, s_t) must pick the true s_t1
  among the batch's (InfoNCE, as in CPC). The paper regresses raw sensor values, a loss weighted by
  each sensor's variance that, where the world moves (MME), must average over the unpredictable
  shift; ranking the true next sensation above the others asks only that it be told apart, the
  objective most self-supervised representation learning now uses. Whether space still emerges
  tells the principle (predict sensorimotor contingencies) from one loss that implements it.

The two models that predict nothing (the autoencoder, the contrastive one) give s_t as their
forward, "no change": their eval_loss is that baseline's error, not a score of theirs.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from smspace.train.model import SensorimotorNet, mlp, prediction_loss


class RandomEncoderNet(SensorimotorNet):
    """The paper's network, its encoder frozen at its initial weights (no gradient reaches them)."""

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            h = self.encoder(torch.cat([m_t, m_t1]))
        h_t, h_t1 = h[: len(m_t)], h[len(m_t) :]
        return prediction_loss(self.predictor(torch.cat([h_t, h_t1, s_t], dim=1)), s_t1)


class MotorAutoencoder(nn.Module):
    """Net_enc as the paper builds it, and a decoder mirroring it back to m."""

    def __init__(
        self, n_motor: int, n_sensor: int, n_h: int, encoder_layers: Sequence[int], predictor_layers: Sequence[int]
    ):
        super().__init__()
        self.encoder = mlp([n_motor, *encoder_layers, n_h])
        self.decoder = mlp([n_h, *reversed(encoder_layers), n_motor])

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return s_t.clone()  # no prediction: "no change"

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        m = torch.cat([m_t, m_t1])
        return prediction_loss(self.decoder(self.encoder(m)), m)


class ContrastiveNet(nn.Module):
    """Net_enc as the paper builds it; a context network (h_t, h_t1, s_t) -> z and a sensation
    network s_t1 -> z, both with the paper's predictor layers; InfoNCE over the batch on the
    cosine similarity of the two, divided by `temperature`."""

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
        embedding: int = 32,
        temperature: float = 0.1,
    ):
        super().__init__()
        if embedding < 1 or not temperature > 0:
            raise ValueError(f"embedding must be >= 1 and temperature > 0 (got {embedding}, {temperature})")
        self.temperature = temperature
        self.encoder = mlp([n_motor, *encoder_layers, n_h])
        self.context = mlp([2 * n_h + n_sensor, *predictor_layers, embedding])
        self.sensation = mlp([n_sensor, *predictor_layers, embedding])

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return s_t.clone()  # no prediction: "no change"

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        h = self.encoder(torch.cat([m_t, m_t1]))
        z = self.context(torch.cat([h[: len(m_t)], h[len(m_t) :], s_t], dim=1))
        target = self.sensation(s_t1)
        z = z / z.norm(dim=1, keepdim=True).clamp_min(1e-8)
        target = target / target.norm(dim=1, keepdim=True).clamp_min(1e-8)
        logits = z @ target.T / self.temperature
        return -logits.log_softmax(dim=1).diagonal().mean()
