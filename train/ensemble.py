"""Many independent runs trained at once as one vectorised model: the runs' own models, whatever
they are, stacked with torch.func (stack_module_state, functional_call, vmap). Run r keeps its
own dataset stream, seed, initial weights and Adam state, so it is the run `smtrain fit` would
train alone; only the summation order of the batched matmuls differs. Each run's slice is exactly
a lone model's state, so every run writes the same folder and checkpoint as `smtrain fit`.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.func import functional_call, stack_module_state, vmap

from smspace.common.errors import SmspaceError
from smspace.train.config import check_resources
from smspace.train.evaluation import N_PREDICTIONS, EvalData
from smspace.train.fit import build
from smspace.train.loop import open_member, recorded_outcome, resolve_device, resume_members, train
from smspace.train.model import prediction_loss
from smspace.train.precision import compiled, step_loss
from smspace.train.run_dir import RunDir


class _Encode(nn.Module):
    """`model.encode` as a forward, for functional_call (which calls forward)."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, m: torch.Tensor) -> torch.Tensor:
        return self.model.encode(m)


class Stacked:
    """R models of one architecture as stacked tensors (R, …), each a leaf the optimiser steps;
    their forward and encode run through vmap over the runs."""

    def __init__(self, models: Sequence[nn.Module]):
        self.params, self.buffers = stack_module_state(list(models))
        self.keys = list(models[0].state_dict())  # the lone model's state-dict order
        base = copy.deepcopy(models[0]).to("meta")
        self._forward = vmap(lambda p, b, *x: functional_call(base, (p, b), x))
        encoder = _Encode(base)
        self._encode = vmap(
            lambda p, b, m: functional_call(
                encoder, ({f"model.{k}": v for k, v in p.items()}, {f"model.{k}": v for k, v in b.items()}), (m,)
            )
        )

    def parameters(self) -> list[torch.Tensor]:
        return list(self.params.values())  # named_parameters order: the lone optimiser's indices

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return self._forward(self.params, self.buffers, m_t, s_t, m_t1)

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self._encode(self.params, self.buffers, m)

    def run_state(self, r: int) -> dict[str, torch.Tensor]:
        tensors = self.params | self.buffers
        return {k: tensors[k][r].detach().clone() for k in self.keys}

    @torch.no_grad()
    def load_run(self, r: int, state: dict[str, torch.Tensor]) -> None:
        for k, tensor in (self.params | self.buffers).items():
            tensor[r].copy_(state[k])


def _adam_state_of_run(stacked: Stacked, opt: torch.optim.Adam, r: int, lr: float) -> dict[str, Any]:
    """Run r's slice of the stacked Adam state, in the layout `torch.optim.Adam.state_dict()` has
    for the lone model (so `smtrain fit --resume` continues a run trained in a sweep)."""
    state = {}
    for i, param in enumerate(stacked.parameters()):
        s = opt.state[param]
        if not s:  # before the first step Adam has no state yet, as in a lone run's step-0 checkpoint
            continue
        state[i] = {
            "step": s["step"].clone(),
            "exp_avg": s["exp_avg"][r].clone(),
            "exp_avg_sq": s["exp_avg_sq"][r].clone(),
        }
    group = {k: v for k, v in opt.param_groups[0].items() if k != "params"} | {"lr": lr}
    return {"state": state, "param_groups": [group | {"params": list(range(len(stacked.parameters())))}]}


def _load_adam_state(stacked: Stacked, opt: torch.optim.Adam, r: int, saved: dict[str, Any]) -> None:
    for i, param in enumerate(stacked.parameters()):
        if i not in saved["state"]:  # a step-0 checkpoint: no moments yet
            continue
        s = opt.state[param]
        if not s:
            s["step"] = torch.zeros((), dtype=torch.float32)
            s["exp_avg"] = torch.zeros_like(param)
            s["exp_avg_sq"] = torch.zeros_like(param)
        src = saved["state"][i]
        s["step"].copy_(src["step"])
        s["exp_avg"][r].copy_(src["exp_avg"])
        s["exp_avg_sq"][r].copy_(src["exp_avg_sq"])


class EnsembleLearner:
    """R runs stacked with one fused Adam: the `Learner` of a sweep."""

    def __init__(
        self,
        stacked: Stacked,
        optimizer: torch.optim.Adam,
        data: list[EvalData],
        precision: str = "fp32",
        compile: bool = False,
    ):
        self.stacked, self.optimizer = stacked, optimizer
        self._loss = compiled(step_loss(stacked.forward, precision, data[0].m_regular.device), compile)
        self.m_regular = torch.stack([d.m_regular for d in data])
        self.eval_inputs = [torch.stack([getattr(d, k) for d in data]) for k in ("m_t", "s_t", "m_t1", "s_t1")]

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]]) -> torch.Tensor:
        device = self.m_regular.device
        m_t, s_t, m_t1, s_t1 = (torch.stack([b[k] for b in batches]).to(device) for k in range(4))
        per_run = self._loss(m_t, s_t, m_t1, s_t1)
        self.optimizer.zero_grad(set_to_none=True)
        per_run.sum().backward()  # parameters are disjoint: each run gets exactly its own gradient
        self.optimizer.step()
        return per_run.detach()

    @torch.no_grad()
    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        h_all = self.stacked.encode(self.m_regular).double().cpu().numpy()
        pred = self.stacked.forward(*self.eval_inputs[:3])
        losses = prediction_loss(pred, self.eval_inputs[3]).cpu().numpy()
        return losses, list(h_all), list(pred[:, :N_PREDICTIONS].cpu().numpy())

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        return {
            "model": self.stacked.run_state(r),
            "optimizer": _adam_state_of_run(self.stacked, self.optimizer, r, lr),
        }

    def load(self, r: int, checkpoint: dict[str, Any]) -> None:
        self.stacked.load_run(r, checkpoint["model"])
        _load_adam_state(self.stacked, self.optimizer, r, checkpoint["optimizer"])


# What runs of one ensemble must share: the model and the schedule the loop applies to all.
SHARED = (
    "steps",
    "batch_size",
    "n_h",
    "encoder_layers",
    "predictor_layers",
    "model",
    "model_params",
    "lr_start",
    "lr_end",
    "lr_decay_steps",
    "eval_every",
    "device",
    "precision",
    "compile",
)


def _check_compatible(cfgs: list) -> None:
    first = cfgs[0].to_dict()
    for cfg in cfgs[1:]:
        other = cfg.to_dict()
        diff = [k for k in SHARED if other[k] != first[k]]
        if diff:
            raise SmspaceError(f"runs of one ensemble must share {', '.join(diff)}")


def train_ensemble(
    runs: list[RunDir],
    resume: bool = False,
    threads: int = 1,
    progress: bool = True,
    on_step: Callable[[int], None] | None = None,
) -> None:
    """Train runs together to their configured steps: from scratch, or (resume) from their
    checkpoints; `on_step` hears the step about every second."""
    torch.set_num_threads(threads)
    device = resolve_device(runs[0].config.device)
    try:
        for run in runs:
            run.claim()  # before anything is recorded: a run another process trains is left untouched
        for run in runs:
            run.record_session(run.config.device, threads)
        _train_claimed(runs, resume, device, progress, on_step)
    finally:
        for run in runs:
            run.release()  # the claims end with the training, however it ends


def _train_claimed(
    runs: list[RunDir], resume: bool, device: torch.device, progress: bool, on_step: Callable[[int], None] | None
) -> None:
    with recorded_outcome(runs):
        members = [open_member(run, run.config, device) for run in runs]
        _check_compatible([m.cfg for m in members])
        manifests = [m.dataset.manifest for m in members]
        n_motor, shape = manifests[0].n_motor, manifests[0].sensor_shape
        if any(mf.n_motor != n_motor or mf.sensor_shape != shape for mf in manifests):
            raise SmspaceError("runs of one ensemble must have datasets of the same setup")
        n_sensor = int(np.prod(shape))
        check_resources(members[0].cfg, manifests[0], runs=len(runs))
        # each run's initial weights are the very ones its lone `fit` draws from its seed
        stacked = Stacked([build(m.cfg, n_motor, n_sensor, device)[0] for m in members])
        opt = torch.optim.Adam(
            stacked.parameters(), lr=members[0].cfg.lr_start, betas=(0.9, 0.999), eps=1e-8, fused=True
        )
        cfg = members[0].cfg
        learner = EnsembleLearner(stacked, opt, [m.data for m in members], cfg.precision, cfg.compile)
        step = resume_members(learner, members, device) if resume else 0
        train(learner, members, step, progress, on_step=on_step)
