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

Four more principles of the field (docs/BENCHMARK.md says why each is here): a β-VAE of the next
sensation whose motor code is a sampled latent (`beta-vae`: noise from the engine, noise_dim), a
latent forward model with a moving-average target (`latent-forward`: after_step), a representation
of displacements (`displacement`), and slowness over the sensory graph (`slow-features`).

The models that predict nothing (the autoencoder, the contrastive, latent-forward and slow-feature
ones) give s_t as their forward, "no change": their eval_loss is that baseline's error, not a score
of theirs.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from smspace.train.model import Dense, SensorimotorNet, mlp, prediction_loss


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


class BetaVAENet(SensorimotorNet):
    """The paper's network whose motor code is a β-VAE's latent (Higgins et al. 2017): the encoder
    gives a Gaussian posterior N(μ(m), σ²(m)) over an N_h-dimensional code, the predictor sees codes
    sampled from it, and the loss adds β times its KL divergence from N(0, I) to the prediction
    error: a generative model of the next sensation conditioned on the motor states, pressed
    towards independent factors. h is the posterior mean μ(m). The sampling's noise is the
    engine's, drawn from the run's seed (train/model.py, noise_dim)."""

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
        beta: float = 0.01,
    ):
        super().__init__(n_motor, n_sensor, n_h, encoder_layers, predictor_layers)
        if not beta >= 0:
            raise ValueError(f"beta must be >= 0 (got {beta})")
        self.beta, self.n_h = beta, n_h
        self.encoder = mlp([n_motor, *encoder_layers, 2 * n_h])  # μ and log σ²
        self.noise_dim = 2 * n_h  # ε for the codes of m_t and m_t1

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)[..., : self.n_h]

    def objective(
        self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor, noise: torch.Tensor
    ) -> torch.Tensor:
        out = self.encoder(torch.cat([m_t, m_t1]))
        mu, log_var = out[:, : self.n_h], out[:, self.n_h :].clamp(-10, 10)
        eps = torch.cat([noise[:, : self.n_h], noise[:, self.n_h :]])
        z = mu + (0.5 * log_var).exp() * eps
        pred = self.predictor(torch.cat([z[: len(m_t)], z[len(m_t) :], s_t], dim=1))
        kl = 0.5 * (mu.pow(2) + log_var.exp() - 1 - log_var).sum(dim=1)  # per motor state
        return prediction_loss(pred, s_t1) + self.beta * 2 * kl.mean()  # two codes per transition


class TargetMLP(nn.Module):
    """A copy of an `mlp`'s weights held as buffers, not parameters: a target network the optimiser
    never steps, which follows its source as an exponential moving average (`follow_`)."""

    def __init__(self, source: nn.Sequential):
        super().__init__()
        self.depth = 0
        for layer in source:
            if isinstance(layer, Dense):
                self.register_buffer(f"w{self.depth}", layer.weight.detach().clone())
                self.register_buffer(f"b{self.depth}", layer.bias.detach().clone())
                self.depth += 1

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i in range(self.depth):
            x = torch.addmm(getattr(self, f"b{i}"), x, getattr(self, f"w{i}"))
            if i < self.depth - 1:
                x = torch.selu(x)
        return x

    def follow_(self, source: nn.Sequential, decay: float) -> None:
        dense = [layer for layer in source if isinstance(layer, Dense)]
        for i, layer in enumerate(dense):
            getattr(self, f"w{i}").mul_(decay).add_(layer.weight, alpha=1 - decay)
            getattr(self, f"b{i}").mul_(decay).add_(layer.bias, alpha=1 - decay)


def cosine_error(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """2 − 2 cos, averaged over the batch: BYOL's loss (the squared distance of unit vectors)."""
    prediction = prediction / prediction.norm(dim=1, keepdim=True).clamp_min(1e-8)
    target = target / target.norm(dim=1, keepdim=True).clamp_min(1e-8)
    return (2 - 2 * (prediction * target).sum(dim=1)).mean()


class LatentForwardNet(nn.Module):
    """Predict the next sensation's *representation*, not the sensation (BYOL, Grill et al. 2020;
    JEPA, LeCun 2022): a sensation encoder g: s -> z, Net_enc m -> h, and a predictor (h_t, h_t1,
    g(s_t)) -> ẑ_t1 trained to point where a target encoder ḡ(s_t1) points (cosine). ḡ is g's
    exponential moving average (`decay` per step, after_step): with a predictor and a slow target
    the embedding does not collapse, and no pixel is ever reconstructed."""

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
        embedding: int = 32,
        decay: float = 0.99,
    ):
        super().__init__()
        if embedding < 1 or not 0 <= decay < 1:
            raise ValueError(f"embedding must be >= 1 and decay in [0, 1) (got {embedding}, {decay})")
        self.decay = decay
        self.encoder = mlp([n_motor, *encoder_layers, n_h])
        self.sensation = mlp([n_sensor, *predictor_layers, embedding])
        self.predictor = mlp([2 * n_h + embedding, *predictor_layers, embedding])
        self.target = TargetMLP(self.sensation)

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return s_t.clone()  # no prediction of s_t1: "no change"

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        h = self.encoder(torch.cat([m_t, m_t1]))
        predicted = self.predictor(torch.cat([h[: len(m_t)], h[len(m_t) :], self.sensation(s_t)], dim=1))
        with torch.no_grad():
            target = self.target(s_t1)
        return cosine_error(predicted, target)

    def after_step(self) -> None:
        self.target.follow_(self.sensation, self.decay)


class DisplacementNet(nn.Module):
    """A representation of the motor *change* (Garcia Ortiz & Laflaquière 2018, "Learning
    representations of spatial displacement through sensorimotor prediction"): Net_enc reads
    (m_t, m_t1) and gives d, the predictor (d, s_t) -> s_t1. The move, not the posture, is encoded.
    Its h of a motor state m is the displacement from the centre of the motor space, d(0 -> m), so
    the bench scores the displacements that start from one posture."""

    def __init__(
        self, n_motor: int, n_sensor: int, n_h: int, encoder_layers: Sequence[int], predictor_layers: Sequence[int]
    ):
        super().__init__()
        self.encoder = mlp([2 * n_motor, *encoder_layers, n_h])
        self.predictor = mlp([n_h + n_sensor, *predictor_layers, n_sensor])

    def displacement(self, m_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return self.encoder(torch.cat([m_t, m_t1], dim=-1))

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.displacement(torch.zeros_like(m), m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return self.predictor(torch.cat([self.displacement(m_t, m_t1), s_t], dim=-1))


class SlowFeatureNet(nn.Module):
    """Slowness over the sensory graph (slow feature analysis, Wiskott & Sejnowski 2002; its graph
    form, Escalante & Wiskott 2013; the place cells of Franzius et al. 2007): h of two motor states
    must be close in proportion to how alike their sensations are, w = exp(−‖s_t1 − s_t‖² / σ²)
    with σ² the batch's mean, while h keeps zero mean and unit, decorrelated variance over the batch
    (SFA's constraints, which make slowness non-trivial, as penalties ‖E h‖² + ‖Cov h − I‖²; without
    the first, the output bias would get no gradient but rounding, which Adam turns into full steps). No sensation is
    predicted: the principle is that what the senses barely tell apart is near."""

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
        whitening: float = 1.0,
    ):
        super().__init__()
        if not whitening > 0:
            raise ValueError(f"whitening must be > 0 (got {whitening})")
        self.whitening = whitening
        self.encoder = mlp([n_motor, *encoder_layers, n_h])

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return s_t.clone()  # no prediction: "no change"

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        h = self.encoder(torch.cat([m_t, m_t1]))
        h_t, h_t1 = h[: len(m_t)], h[len(m_t) :]
        change = (s_t1 - s_t).pow(2).sum(dim=1)
        weight = torch.exp(-change / change.mean().clamp_min(1e-12)).detach()
        slowness = (weight * (h_t1 - h_t).pow(2).sum(dim=1)).sum() / weight.sum()
        mean = h.mean(dim=0)
        centred = h - mean
        cov = centred.T @ centred / (len(h) - 1)
        eye = torch.eye(h.shape[1], dtype=h.dtype, device=h.device)
        return slowness + self.whitening * (mean.pow(2).sum() + (cov - eye).pow(2).sum())


class PathIntegratorNet(nn.Module):
    """A recurrent path integrator (the place- and grid-cell line: Cueva & Wei 2018, Banino et al.
    2018 trained recurrent networks to integrate velocities), the model that reads walks: h of a
    window's first posture from Net_enc, every later h integrated from the motor changes alone,
    h_k+1 = h_k + Net_int(h_k, m_t1_k − m_t_k), and each step's sensation predicted from (h_k, h_k+1,
    s_t_k) as the paper's predictor does. A consistency term ‖h_k+1 − Net_enc(m_t1_k)‖² ties the
    integrated state to the encoded one, so encode(m), which the metrics read, is where integration
    arrives. An integration error compounds over the window: the longer it is, the more h must be a
    space in which a motor change acts as the same displacement wherever it starts. With one step
    (transitions, or --window 1) it is the paper's network whose h_t1 is integrated from the move."""

    reads_windows = True  # the engine gives its objective (B, K, ·) windows (train/model.py)

    def __init__(
        self,
        n_motor: int,
        n_sensor: int,
        n_h: int,
        encoder_layers: Sequence[int],
        predictor_layers: Sequence[int],
        consistency: float = 1.0,
        integrator_layers: Sequence[int] = (100,),
    ):
        super().__init__()
        if not consistency >= 0:
            raise ValueError(f"consistency must be >= 0 (got {consistency})")
        self.consistency = float(consistency)
        self.encoder = mlp([n_motor, *encoder_layers, n_h])
        self.integrator = mlp([n_h + n_motor, *integrator_layers, n_h])
        self.predictor = mlp([2 * n_h + n_sensor, *predictor_layers, n_sensor])

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def integrate(self, h: torch.Tensor, move: torch.Tensor) -> torch.Tensor:
        return h + self.integrator(torch.cat([h, move], dim=-1))

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        h_t = self.encoder(m_t)
        return self.predictor(torch.cat([h_t, self.integrate(h_t, m_t1 - m_t), s_t], dim=-1))

    def objective(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor) -> torch.Tensor:
        steps = m_t.shape[1]  # (B, K, ·): K from the shape, the same on every call of a run
        encoded = self.encoder(m_t1)
        h, predicted, consistent = self.encoder(m_t[:, 0]), 0.0, 0.0
        for k in range(steps):
            h_next = self.integrate(h, m_t1[:, k] - m_t[:, k])
            pred = self.predictor(torch.cat([h, h_next, s_t[:, k]], dim=-1))
            predicted = predicted + prediction_loss(pred, s_t1[:, k])
            consistent = consistent + (h_next - encoded[:, k]).pow(2).sum(dim=-1).mean()
            h = h_next
        return (predicted + self.consistency * consistent) / steps
