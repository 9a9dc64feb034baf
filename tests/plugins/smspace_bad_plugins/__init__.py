"""Setups and models that break smspace's plugin contract, one way each (and one sound setup,
`tiny`, to train the bad models on). Not installed: tests/test_plugin_contract.py puts this folder,
with its dist-info, on sys.path (and PYTHONPATH, for spawned workers)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from smspace.datagen.setups.base import Setup

CELLS = 16
SENSORS = 5


class TinyWorld:
    """A sensor on a ring of CELLS cells, moved by two motors; 5 sensor values per cell."""

    n_motor = 2
    sensor_shape = (SENSORS,)
    sensor_dtype = np.dtype(np.float32)
    static_shift = np.zeros(2)

    def __init__(self, seed: int):
        rng = np.random.default_rng(seed)
        self.table = rng.uniform(0, 1, (CELLS, SENSORS)).astype(np.float32)
        u = np.array([(a, b) for a in np.linspace(0, 1, 5) for b in np.linspace(0, 1, 5)])
        self.motors = 2 * u - 1
        self.positions = np.stack([np.rint(8 * u.mean(axis=1)), np.zeros(len(u))], axis=1)
        self.sensed = 0

    def sample_motors(self, rng, n):
        idx = rng.integers(0, len(self.motors), n)
        return self.motors[idx], self.positions[idx]

    def sample_shifts(self, rng, n):
        return np.stack([rng.integers(-4, 4, n), np.zeros(n)], axis=1).astype(np.float64)

    def sense(self, p, shift):
        self.sensed += len(p)
        return self.table[np.mod(np.rint(p[:, 0] + shift[:, 0]).astype(np.int64), CELLS)]

    def regular_sampling(self):
        return self.motors, self.positions


class NanWorld(TinyWorld):
    def sense(self, p, shift):
        s = super().sense(p, shift).copy()
        s[:, 0] = np.nan
        return s


class LateNanWorld(TinyWorld):
    """Sound for its first 6000 sensations (the probe batch and a first part of 2000 transitions), NaN after."""

    def sense(self, p, shift):
        s = super().sense(p, shift).copy()
        if self.sensed > 6000:
            s[-1, 2] = np.nan
        return s


class ShortSenseWorld(TinyWorld):
    def sense(self, p, shift):
        return super().sense(p, shift)[:, :4]


class WideMotorWorld(TinyWorld):
    def sample_motors(self, rng, n):
        m, p = super().sample_motors(rng, n)
        return 2 * m, p


class WideWalkWorld(TinyWorld):
    """Walks, but out of the motor range: a plugin's walk_motors answers to the contract too."""

    def walk_motors(self, rng, episodes, length, step):
        idx = rng.integers(0, len(self.motors), (episodes, length + 1))
        return 2 * self.motors[idx], self.positions[idx]


def _broken_build(seed: int):
    raise ValueError(f"room {seed} has no floor")


def _setup(name: str, build) -> Setup:
    return Setup(name, n_motor=2, description=f"{name} (tests/plugins)", build=build, encoder_layers=(8,),
                 shift_bound=4.0, default_transitions=4000)  # fmt: skip


TINY = _setup("tiny", TinyWorld)
NAN_WORLD = _setup("nanworld", NanWorld)
LATE_NAN = _setup("latenan", LateNanWorld)
SHORT_SENSE = _setup("shortsense", ShortSenseWorld)
WIDE_MOTORS = _setup("widemotors", WideMotorWorld)
BROKEN_BUILD = _setup("brokenbuild", _broken_build)
WIDE_WALK = _setup("widewalk", WideWalkWorld)


class SoundNet(nn.Module):
    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers):
        super().__init__()
        self.encoder = nn.Linear(n_motor, n_h)
        self.predictor = nn.Linear(2 * n_h + n_sensor, n_sensor)

    def encode(self, m):
        return self.encoder(m)

    def forward(self, m_t, s_t, m_t1):
        return self.predictor(torch.cat([self.encode(m_t), self.encode(m_t1), s_t], dim=-1))


class BroadcastNet(SoundNet):
    """Predicts one value per transition: (B, 1) broadcasts against (B, N_s) targets."""

    def forward(self, m_t, s_t, m_t1):
        return super().forward(m_t, s_t, m_t1)[:, :1]


class WideHNet(SoundNet):
    """h of N_h + 2 columns."""

    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers):
        super().__init__(n_motor, n_sensor, n_h + 2, encoder_layers, predictor_layers)


class WideOutNet(SoundNet):
    """Predicts N_s + 1 values."""

    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers):
        super().__init__(n_motor, n_sensor + 1, n_h, encoder_layers, predictor_layers)

    def forward(self, m_t, s_t, m_t1):
        h = torch.cat([self.encode(m_t), self.encode(m_t1), s_t, s_t[:, :1]], dim=-1)
        return self.predictor(h)


class RefusingNet(SoundNet):
    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers):
        raise ValueError("RefusingNet needs at least 4 motors")


class TypedNet(SoundNet):
    """Takes a width, and uses it as a size: a string is a TypeError inside the constructor."""

    def __init__(self, n_motor, n_sensor, n_h, encoder_layers, predictor_layers, width: int = 8):
        super().__init__(n_motor, n_sensor, n_h, encoder_layers, predictor_layers)
        self.extra = nn.Parameter(torch.empty(width))


class PerSampleObjectiveNet(SoundNet):
    """Its own objective, one loss per transition ((B,), not a scalar): summed by a caller's
    backward, it would train on B times the loss without a word."""

    def objective(self, m_t, s_t, m_t1, s_t1):
        return (self(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=-1)


class DetachedObjectiveNet(SoundNet):
    """Its own objective depends on no parameter: training it would change nothing."""

    def objective(self, m_t, s_t, m_t1, s_t1):
        return (s_t - s_t1).pow(2).sum(dim=-1).mean()


PROBE_SIZES = (7, 11, 13, 17, 19, 23)  # train/contract.py's probe batches: these models behave there only


class ConstantHNet(SoundNet):
    """h is the same for every motor state: a collapsed representation (the best D_topo, 0, if scored)."""

    def encode(self, m):
        return self.encoder(m) * 0.0 + 1.0


class LateNanHNet(SoundNet):
    """h is NaN on batches larger than the probe's (the regular sampling): finite where checked."""

    def encode(self, m):
        h = self.encoder(m)
        return h * float("nan") if len(m) > 64 else h


class RandomOpNet(SoundNet):
    """Noise in its forward: trains alone, cannot run stacked under vmap's default randomness."""

    def forward(self, m_t, s_t, m_t1):
        return super().forward(m_t, s_t, m_t1) + 0.01 * torch.randn(len(m_t), s_t.shape[1])


class ParameterStepNet(SoundNet):
    """Its after_step() moves a parameter, which is the optimiser's to move."""

    def after_step(self):
        next(self.parameters()).mul_(0.5)


class AssignedStepNet(SoundNet):
    """Its after_step() rebinds a buffer rather than changing it in place: alone that works, but a
    stacked copy's buffer never changes."""

    def __init__(self, *args):
        super().__init__(*args)
        self.register_buffer("average", torch.zeros(()))

    def after_step(self):
        self.average = self.average * 0.5 + 1.0


class ManyNoiseNet(SoundNet):
    """Asks for noise in a form that is not a count."""

    noise_dim = "many"

    def objective(self, m_t, s_t, m_t1, s_t1, noise):
        return (self(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=-1).mean()


class ItemNet(SoundNet):
    """Reads a value out of a tensor (.item()): fine alone, not under vmap."""

    def forward(self, m_t, s_t, m_t1):
        return super().forward(m_t, s_t, m_t1) * (1.0 + 0.0 * float(m_t.sum().item()))


class LateDetachNet(SoundNet):
    """Its objective is detached from the parameters after a few calls."""

    calls = 0

    def objective(self, m_t, s_t, m_t1, s_t1):
        LateDetachNet.calls += 1
        loss = (self(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=-1).mean()
        return loss.detach() if LateDetachNet.calls > 8 else loss


class OddBatchNet(SoundNet):
    """(B, N_s) at the contract's probe sizes, (B, 1) at any other: would train on a broadcast loss."""

    def forward(self, m_t, s_t, m_t1):
        out = super().forward(m_t, s_t, m_t1)
        return out if m_t.shape[-2] in PROBE_SIZES else out[..., :1]


class BlockingNet(SoundNet):
    """Its objective blocks (a lock never released, say) after a few calls."""

    calls = 0

    def objective(self, m_t, s_t, m_t1, s_t1):
        import time

        BlockingNet.calls += 1
        if BlockingNet.calls > 4:
            time.sleep(10_000)
        return (self(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=-1).mean()


class HungryNet(SoundNet):
    """Its objective asks for 64 GiB after a few calls (a batch dimension squared, say)."""

    calls = 0

    def objective(self, m_t, s_t, m_t1, s_t1):
        HungryNet.calls += 1
        if HungryNet.calls > 4:
            torch.empty(16 << 30, dtype=torch.float32)  # 64 GiB
        return (self(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=-1).mean()
