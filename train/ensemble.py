"""The stacking behind an ensemble: R models of one architecture, whatever it is, as one
vectorised model with torch.func (stack_module_state, functional_call, vmap), and run r's slice of
the stacked Adam state. Run r keeps its own dataset stream, seed, initial weights and Adam state
(train/engine.py, EnsembleLearner), so it is the run `smtrain fit` would train alone; only the
summation order of the batched matmuls differs. Each run's slice is exactly a lone model's state,
so every run writes the same folder and checkpoint as `smtrain fit`.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn
from torch.func import functional_call, stack_module_state, vmap

from smspace.train.model import Effect, Method, has_after_step


class Stacked:
    """R models of one architecture as stacked tensors (R, …), each a leaf the optimiser steps;
    their forward and encode run through vmap over the runs."""

    def __init__(self, models: Sequence[nn.Module]):
        self.params, self.buffers = stack_module_state(list(models))
        self.keys = list(models[0].state_dict())  # the lone model's state-dict order
        base = copy.deepcopy(models[0]).to("meta")
        self.model = base  # the architecture (meta tensors): what it is, not its weights
        self._forward = vmap(lambda p, b, *x: functional_call(base, (p, b), x))
        self._encode, self._objective = _vmapped(Method(base, "encode")), _vmapped(Method(base, "objective"))
        self._after_step = _vmapped(Effect(base, "after_step")) if has_after_step(base) else None

    def parameters(self) -> list[torch.Tensor]:
        return list(self.params.values())  # named_parameters order: the lone optimiser's indices

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        return self._forward(self.params, self.buffers, m_t, s_t, m_t1)

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self._encode(self.params, self.buffers, m)

    def objective(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Each run's own loss, (R,), for models that define one (train/model.py, has_objective):
        (m_t, s_t, m_t1, s_t1), and each run's noise where the model asks for it."""
        return self._objective(self.params, self.buffers, *inputs)

    @torch.no_grad()
    def after_step(self) -> None:
        """Each run's after_step() on its own slice: its buffers change in place, as a lone model's."""
        if self._after_step is not None:
            self._after_step(self.params, self.buffers)

    def run_state(self, r: int) -> dict[str, torch.Tensor]:
        tensors = self.params | self.buffers
        return {k: tensors[k][r].detach().clone() for k in self.keys}

    @torch.no_grad()
    def load_run(self, r: int, state: dict[str, torch.Tensor]) -> None:
        for k, tensor in (self.params | self.buffers).items():
            tensor[r].copy_(state[k])


def _vmapped(method: Method):
    """A method of the model run on each run's slice of the stacked state."""

    def call(p: dict[str, torch.Tensor], b: dict[str, torch.Tensor], *x: torch.Tensor) -> torch.Tensor:
        named = {f"model.{k}": v for k, v in p.items()}, {f"model.{k}": v for k, v in b.items()}
        return functional_call(method, named, x)

    return vmap(call)


def adam_state_of_run(stacked: Stacked, opt: torch.optim.Adam, r: int, lr: float) -> dict[str, Any]:
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


def load_adam_state(stacked: Stacked, opt: torch.optim.Adam, r: int, saved: dict[str, Any]) -> None:
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
