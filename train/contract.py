"""The contract every model is held to (docs/API.md, "Plugins"), checked once on a probe batch
before a run folder is written: `forward(m_t, s_t, m_t1)` gives exactly (B, N_s) float32 for
(B, N_s) targets (a (B, 1) output would broadcast in the loss and train silently), `encode(m)`
exactly (B, N_h), both finite; a model's own `objective(m_t, s_t, m_t1, s_t1)`, where it has one,
a finite float32 scalar that backpropagates. Sweeps and `smtrain bench` train runs stacked (vmap,
train/ensemble.py), so the probe also runs two stacked copies: what cannot run there (random ops
such as torch.randn or dropout, `.item()`, data-dependent control flow) is refused here, not 90
lines into a bench; a model that needs noise asks the engine for it (`noise_dim`), and one with
state of its own (`after_step()`) must update only buffers, alone and stacked alike. The probe's
batch sizes are not the only ones checked: the engine holds the real batches to the same shapes
once per session and at every evaluation (`check_outputs`).
Broken, it is one line naming the model and what it gave.
"""

from __future__ import annotations

from typing import Any

import torch

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.common.limits import STEP_LIMIT_ENV, step_limit_s, time_limit
from smspace.train.config import TrainConfig
from smspace.train.model import (
    build_model,
    has_after_step,
    has_objective,
    model_label,
    model_plugin,
    noise_dim,
    prediction_loss,
    reads_windows,
)


def probe_batch_size(*sizes: int) -> int:
    """A batch whose size equals no other dimension, so that a swapped or broadcast axis shows."""
    return next(b for b in (7, 11, 13, 17, 19, 23) if b not in sizes)


def check_model(cfg: TrainConfig, n_motor: int, n_sensor: int, stacked: bool = False) -> None:
    """Build the config's model and run it once, forward and backward, on a probe batch (and, for
    runs that will train `stacked`, as two stacked copies): one line if it breaks the contract.
    Leaves torch's random state as it found it."""
    label, limit_s = model_label(cfg.model), step_limit_s()

    def too_long() -> SmspaceError:
        return SmspaceError(f"{label} took more than {limit_s:g} s on a probe batch (${STEP_LIMIT_ENV} bounds a step)")

    with time_limit(limit_s, too_long):
        _probe(cfg, n_motor, n_sensor, stacked)


def _probe(cfg: TrainConfig, n_motor: int, n_sensor: int, stacked: bool) -> None:
    name, n_h = cfg.model, cfg.n_h
    plugin, label = model_plugin(name), model_label(name)
    batch = probe_batch_size(n_motor, n_sensor, n_h)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        layers = cfg.encoder_layers, cfg.predictor_layers
        model = build_model(name, n_motor, n_sensor, n_h, *layers, cfg.model_params)
        generator = torch.Generator().manual_seed(0)
        m_t = torch.rand(batch, n_motor, generator=generator) * 2 - 1
        m_t1 = torch.rand(batch, n_motor, generator=generator) * 2 - 1
        s_t = torch.rand(batch, n_sensor, generator=generator)
        with plugins.guarded(plugin, "in forward() on a probe batch"):
            pred = model(m_t, s_t, m_t1)
        _expect(label, "forward(m_t, s_t, m_t1)", pred, (batch, n_sensor), batch, f"(B, N_s) = ({batch}, {n_sensor})")
        with plugins.guarded(plugin, "in encode() on a probe batch"):
            h = model.encode(m_t)
        _expect(label, "encode(m)", h, (batch, n_h), batch, f"(B, N_h) = ({batch}, {n_h})")
        if not any(p.requires_grad for p in model.parameters()):
            raise SmspaceError(f"{label} has no trainable parameters")
        with plugins.guarded(plugin, "in its reads_windows"):
            windows = _check_windows(model, label, cfg.window)
        with plugins.guarded(plugin, "in its noise_dim"):
            dim = noise_dim(model, label)
        noise = [torch.randn(batch, dim, generator=generator)] if dim else []
        if windows:  # its objective's batch: windows of K steps that follow on (m_t1 of k is m_t of k + 1)
            m_t, s_t, m_t1 = _probe_windows(batch, cfg.window, n_motor, n_sensor, generator)
        if has_objective(model):
            s_t1 = torch.rand(*s_t.shape, generator=generator)
            with plugins.guarded(plugin, "in objective() on a probe batch"):
                loss = model.objective(m_t, s_t, m_t1, s_t1, *noise)
            call = f"objective() on windows of {cfg.window} steps" if windows else "objective(m_t, s_t, m_t1, s_t1)"
            _expect(label, call, loss, (), batch, "a scalar, shape () (the batch's mean)")
        else:
            loss = prediction_loss(pred, s_t)
        if not loss.requires_grad:
            raise SmspaceError(f"{label}: its training loss does not depend on any trainable parameter")
        with plugins.guarded(plugin, "in backward() on a probe batch"):
            loss.backward()
        if has_after_step(model):
            with plugins.guarded(plugin, "in after_step()"):
                _check_after_step(model, label)
        if stacked:
            inputs = (m_t, s_t, m_t1, torch.rand(*s_t.shape, generator=generator), *noise)
            _check_stacked(model, label, inputs)


def _check_windows(model: torch.nn.Module, label: str, window: int) -> bool:
    """Whether the model reads windows (train/model.py, reads_windows); a window asked of a model
    that reads single transitions, or windows for a model with no objective to read them, is one line."""
    windows = reads_windows(model)
    if window > 1 and not windows:
        raise SmspaceError(
            f"{label} reads single transitions; --window {window} needs a model that reads windows "
            "(reads_windows = True, docs/API.md)"
        )
    if windows and not has_objective(model):
        raise SmspaceError(f"{label} reads windows (reads_windows) but has no objective() to be given them")
    return windows


def _probe_windows(
    batch: int, steps: int, n_motor: int, n_sensor: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """m_t, s_t, m_t1 of `batch` windows of `steps` consecutive steps, (B, K, ·)."""
    m = torch.rand(batch, steps + 1, n_motor, generator=generator) * 2 - 1
    s = torch.rand(batch, steps, n_sensor, generator=generator)
    return m[:, :-1].contiguous(), s, m[:, 1:].contiguous()


def _check_after_step(model: torch.nn.Module, label: str) -> None:
    """after_step() may change the model's buffers, in place, never its parameters (the optimiser's:
    a change there would go unrecorded in Adam's state and differ under DDP's averaging)."""
    before = {k: v.detach().clone() for k, v in model.named_parameters()}
    with torch.no_grad():
        model.after_step()
    moved = [k for k, v in model.named_parameters() if not torch.equal(v, before[k])]
    if moved:
        raise SmspaceError(f"{label}: after_step() changed parameter {moved[0]}; it may change only buffers")


def _check_stacked(model: torch.nn.Module, label: str, batch: tuple[torch.Tensor, ...]) -> None:
    """Two copies of the model stacked as an ensemble stacks them, one step forward and back."""
    import copy

    from smspace.train.ensemble import Stacked

    stacked = Stacked([model, copy.deepcopy(model)])
    two = [torch.stack([x, x]) for x in batch]
    try:
        loss = stacked.objective(*two) if has_objective(model) else prediction_loss(stacked.forward(*two[:3]), two[3])
        loss.sum().backward()
        if has_after_step(model):
            alone = copy.deepcopy(model)
            with torch.no_grad():
                alone.after_step()
            stacked.after_step()
            expected, got = alone.state_dict(), stacked.run_state(1)
            differs = [k for k in expected if not torch.allclose(got[k], expected[k], rtol=1e-5, atol=1e-6)]
            if differs:
                raise SmspaceError(
                    f"{label}: after_step() on a stacked copy did not update {differs[0]} as it does alone "
                    f"(it must change its buffers in place, with tensor operations only)"
                )
    except SmspaceError:
        raise
    except Exception as e:  # whatever vmap refuses: one line, as raised
        raise SmspaceError(
            f"{label} cannot be trained stacked (sweeps and `smtrain bench` train runs together with "
            f"torch.func.vmap, which has no random ops, .item() or branches on values): "
            f"{type(e).__name__}: {_first_line(e)}"
        ) from None


def _first_line(e: BaseException) -> str:
    lines = [line for line in str(e).splitlines() if line.strip()]
    return lines[0][:300] if lines else type(e).__name__


def check_outputs(
    label: str, loss: torch.Tensor, pred: torch.Tensor | None, target: torch.Tensor, stacked: bool
) -> None:
    """The shapes of a real training step: its loss one scalar per run, its prediction exactly the
    target's shape (a (B, 1) prediction would broadcast). Called on the batches really trained on,
    once per session and at every evaluation: a model may behave at batch sizes the probe never tried."""
    runs = 1 if stacked else 0  # a stacked ensemble's outputs lead with the run axis: shapes are per run
    if tuple(loss.shape[runs:]) != () or (stacked and loss.ndim != 1):
        raise SmspaceError(f"{label}: its training loss has shape {tuple(loss.shape[runs:])} on a batch of "
                           f"{target.shape[-2]}; it must be a scalar (the batch's mean)")  # fmt: skip
    if pred is not None and tuple(pred.shape) != tuple(target.shape):
        raise SmspaceError(
            f"{label}: forward(m_t, s_t, m_t1) gave shape {tuple(pred.shape[runs:])} on a batch of "
            f"{target.shape[-2]}; it must give exactly {tuple(target.shape[runs:])} (no broadcasting)"
        )


def _expect(label: str, call: str, out: Any, shape: tuple[int, ...], batch: int, spelled: str) -> None:
    if not isinstance(out, torch.Tensor):
        raise SmspaceError(f"{label}: {call} returned a {type(out).__name__}, not a tensor")
    if tuple(out.shape) != shape:
        raise SmspaceError(
            f"{label}: {call} gave shape {tuple(out.shape)} on a probe batch of {batch}; "
            f"it must give exactly {spelled} (no broadcasting)"
        )
    if out.dtype != torch.float32:
        raise SmspaceError(f"{label}: {call} gave {out.dtype} for float32 inputs; it must give float32")
    bad = int((~torch.isfinite(out)).sum())
    if bad:
        raise SmspaceError(f"{label}: {call} gave {bad} non-finite value(s) (NaN or inf) on a probe batch")
