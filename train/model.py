"""The networks a run can train: the sensorimotor predictive network of docs/MODEL.md §3 (a siamese
motor encoder and a sensory predictor), and any model another package registers.

A model is a torch module built as `Model(n_motor, n_sensor, n_h, encoder_layers, predictor_layers,
**params)` with `encode(m) -> h` and `forward(m_t, s_t, m_t1) -> predicted s_t1`. Another package
registers one under the entry-point group `smspace.models` (docs/API.md, "Plugins"); `smtrain fit
--model NAME` and study files name it, and config.json records its name and parameters.

Two optional hooks give a model what a lone run, a stacked ensemble and DDP must all treat alike:
`noise_dim` (standard-normal noise drawn by the engine from the run's seed, handed to its objective)
and `after_step()` (state of its own, such as an EMA target, updated after each optimiser step).
"""

from __future__ import annotations

import inspect
import itertools
import math
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.common.plugins import Plugin
from smspace.train.config import MODELS


class Dense(nn.Module):
    """A linear layer whose weight is stored (in, out): `x @ W + b` in one addmm, which the
    ensembles' vmap turns into one batched matmul without transposed copies (nn.Linear's (out,
    in) weight cost a third more time per step there). Glorot-uniform weights drawn as a (out, in)
    matrix then transposed, so a seed gives the weights it always gave; zero biases."""

    def __init__(self, in_features: int, out_features: int):
        super().__init__()
        self.in_features, self.out_features = in_features, out_features
        weight = torch.empty(out_features, in_features)
        nn.init.xavier_uniform_(weight)  # TF1 dense default, not PyTorch's Kaiming
        self.weight = nn.Parameter(weight.t().contiguous())
        self.bias = nn.Parameter(torch.zeros(out_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() == 2:
            return torch.addmm(self.bias, x, self.weight)
        return x @ self.weight + self.bias


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Dense layers with SELU between them and a linear output."""
    layers: list[nn.Module] = []
    for i, (fan_in, fan_out) in enumerate(itertools.pairwise(sizes)):
        layers.append(Dense(fan_in, fan_out))
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
        h = self.encode(torch.cat([m_t, m_t1]))
        h_t, h_t1 = h[: len(m_t)], h[len(m_t) :]
        return self.predictor(torch.cat([h_t, h_t1, s_t], dim=1))


def prediction_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared error summed over sensor components, averaged over the batch (not mse_loss)."""
    return (pred - target).pow(2).sum(dim=-1).mean(dim=-1)


def has_objective(model: nn.Module) -> bool:
    """Whether a model trains on a loss of its own, `objective(m_t, s_t, m_t1, s_t1)` (a scalar),
    rather than the prediction loss of its forward: a benchmark entry that learns otherwise (an
    autoencoder of motor states, a contrastive objective) is a model like any other."""
    return callable(getattr(model, "objective", None))


def reads_windows(model: nn.Module) -> bool:
    """Whether a model trains on windows of consecutive steps (its `reads_windows` attribute, True):
    its objective is given (B, K, ·) tensors, K = the run's `--window` (1 included), where every
    other model is given (B, ·) transitions. Its forward and encode stay per transition, so its
    evaluation (the prediction loss on fixed transitions, h of the regular sampling) is everyone's."""
    return getattr(model, "reads_windows", False) is True


def as_windows(x: torch.Tensor, step_axis: int) -> torch.Tensor:
    """A batch column as windows: a (B, ·) column of single transitions gains a step axis of 1."""
    return x.unsqueeze(step_axis) if x.dim() == step_axis + 1 else x


NOISE_LIMIT = 4096  # standard-normal numbers per row a model may ask for


def noise_dim(model: nn.Module, label: str = "") -> int:
    """How many standard-normal numbers per row of a batch a model's objective is given (its
    `noise_dim` attribute; 0 or absent: none). A model must not draw them itself: torch.randn would
    differ between a lone run and the same run stacked (vmap has no per-run generator) and could not
    be repeated from the run's seed. The engine draws them instead (train/engine.py, step_noise) and
    passes them as `objective(m_t, s_t, m_t1, s_t1, noise)`, noise (B, noise_dim)."""
    dim, who = getattr(model, "noise_dim", 0), label or type(model).__name__
    if isinstance(dim, bool) or not isinstance(dim, int) or not 0 <= dim <= NOISE_LIMIT:
        raise SmspaceError(f"{who}: noise_dim must be an int in 0..{NOISE_LIMIT}, not {dim!r:.40}")
    if dim and not has_objective(model):
        raise SmspaceError(f"{who} asks for noise (noise_dim) but has no objective() to be given it")
    return dim


def has_after_step(model: nn.Module) -> bool:
    """Whether a model updates state of its own after each optimiser step, `after_step()` (called
    under no_grad): a target network that follows the online one as an exponential moving average.
    It may change only the model's buffers, in place; parameters are the optimiser's (the contract
    checks both, and that two stacked copies update as each would alone)."""
    return callable(getattr(model, "after_step", None))


class Method(nn.Module):
    """One method of a model as a module's forward: what DDP wraps (its gradient hooks fire only
    through forward) and what an ensemble's functional_call runs."""

    def __init__(self, model: nn.Module, name: str):
        super().__init__()
        self.model, self.name = model, name

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return getattr(self.model, self.name)(*inputs)


class Effect(Method):
    """A method called for what it changes (after_step): vmap needs a tensor back, so a 0 stands in."""

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        getattr(self.model, self.name)(*inputs)
        return torch.zeros(())


def model_plugin(name: str) -> Plugin | None:
    """The package a model comes from (None: smspace's own)."""
    return MODELS.plugin(name)


def model_label(name: str) -> str:
    return MODELS.label(name)


def plugin_record(name: str) -> dict[str, str]:
    """What config.json records of the model's code ({} for smspace's own, which smspace's version
    and git commit already name)."""
    plugin = model_plugin(name)
    return plugin.record() if plugin is not None else {}


def build_model(
    name: str,
    n_motor: int,
    n_sensor: int,
    n_h: int,
    encoder_layers: Sequence[int],
    predictor_layers: Sequence[int],
    params: dict[str, Any] | None = None,
) -> nn.Module:
    """A model by name, with its own parameters. Parameters its constructor does not take are one
    line; whatever its constructor raises is one line naming it, as raised."""
    cls, plugin = MODELS.get(name), MODELS.plugin(name)
    args = (n_motor, n_sensor, n_h, list(encoder_layers), list(predictor_layers))
    try:
        inspect.signature(cls).bind(*args, **(params or {}))
    except TypeError as e:
        raise SmspaceError(f"model {name!r} does not take these parameters ({e})") from None
    except ValueError:  # no signature to read (a builtin): the call itself says
        pass
    with plugins.guarded(plugin, "in its constructor"):
        model = cls(*args, **(params or {}))
    if not isinstance(model, nn.Module):
        raise SmspaceError(f"model {name!r} built a {type(model).__name__}, not a torch.nn.Module")
    for method in ("encode", "forward"):
        if not callable(getattr(model, method, None)):
            raise SmspaceError(f"model {name!r} has no {method}(); a model encodes m and predicts s_t1")
    return model


def parameter_count(model: nn.Module) -> int:
    return sum(math.prod(p.shape) for p in model.parameters())
