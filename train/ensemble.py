"""Many independent runs trained at once as one vectorised model (batched matmuls over a runs
dimension). Run r keeps its own dataset stream, seed, initial weights and Adam state, so it is
mathematically the run `smtrain fit` would train alone; only the summation order of the matmuls
differs. Every run writes the same folder as `smtrain fit`, checkpoint format included.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from smspace.common.errors import SmspaceError
from smspace.train.config import TrainConfig, check_resources
from smspace.train.evaluation import N_PREDICTIONS, EvalData
from smspace.train.fit import build
from smspace.train.loop import open_member, recorded_outcome, resolve_device, resume_members, train
from smspace.train.run_dir import RunDir
from torch import nn


class EnsembleMLP(nn.Module):
    """R MLPs side by side: weights (R, in, out), biases (R, 1, out); SELU between layers."""

    def __init__(self, runs: int, sizes: list[int]):
        super().__init__()
        self.weights = nn.ParameterList(nn.Parameter(torch.empty(runs, a, b)) for a, b in itertools.pairwise(sizes))
        self.biases = nn.ParameterList(nn.Parameter(torch.zeros(runs, 1, b)) for b in sizes[1:])

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

    def encode(self, m: torch.Tensor) -> torch.Tensor:
        return self.encoder(m)

    def forward(self, m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor) -> torch.Tensor:
        b = m_t.shape[1]
        h = self.encoder(torch.cat([m_t, m_t1], dim=1))
        return self.predictor(torch.cat([h[:, :b], h[:, b:], s_t], dim=2))

    # -- the mapping to and from one SensorimotorNet ------------------------------------------------
    def _pairs(self) -> list[tuple[str, nn.Parameter, bool]]:
        """(single-run parameter name, stacked parameter, is a weight) in SensorimotorNet's order."""
        pairs = []
        for prefix, mlp in (("encoder", self.encoder), ("predictor", self.predictor)):
            for i, (w, b) in enumerate(zip(mlp.weights, mlp.biases, strict=True)):
                pairs += [(f"{prefix}.{2 * i}.weight", w, True), (f"{prefix}.{2 * i}.bias", b, False)]
        return pairs

    @staticmethod
    def _to_stacked(x: torch.Tensor, is_weight: bool) -> torch.Tensor:
        return x.t() if is_weight else x.unsqueeze(0)  # Linear keeps (out, in) and (out,)

    @staticmethod
    def _to_single(x: torch.Tensor, is_weight: bool) -> torch.Tensor:
        return x.t().contiguous() if is_weight else x.squeeze(0).contiguous()

    @torch.no_grad()
    def load_run(self, r: int, state: dict[str, torch.Tensor]) -> None:
        for name, param, is_weight in self._pairs():
            param[r].copy_(self._to_stacked(state[name], is_weight))

    def run_state(self, r: int) -> dict[str, torch.Tensor]:
        return {name: self._to_single(p.detach()[r], w).clone() for name, p, w in self._pairs()}


def _adam_state_of_run(net: EnsembleNet, opt: torch.optim.Adam, r: int, lr: float) -> dict[str, Any]:
    """Run r's slice of the stacked Adam state, in the layout `torch.optim.Adam.state_dict()` has
    for a lone SensorimotorNet (so `smtrain fit --resume` continues a run trained in a sweep)."""
    state = {}
    for i, (_, param, is_weight) in enumerate(net._pairs()):
        s = opt.state[param]
        if not s:  # before the first step Adam has no state yet, as in a lone run's step-0 checkpoint
            continue
        state[i] = {
            "step": s["step"].clone(),
            "exp_avg": net._to_single(s["exp_avg"][r], is_weight),
            "exp_avg_sq": net._to_single(s["exp_avg_sq"][r], is_weight),
        }
    group = {k: v for k, v in opt.param_groups[0].items() if k != "params"} | {"lr": lr}
    return {"state": state, "param_groups": [group | {"params": list(range(len(net._pairs())))}]}


def _load_adam_state(net: EnsembleNet, opt: torch.optim.Adam, r: int, saved: dict[str, Any]) -> None:
    for i, (_, param, is_weight) in enumerate(net._pairs()):
        s = opt.state[param]
        if not s:
            s["step"] = torch.zeros((), dtype=torch.float32)
            s["exp_avg"] = torch.zeros_like(param)
            s["exp_avg_sq"] = torch.zeros_like(param)
        src = saved["state"][i]
        s["step"].copy_(src["step"])
        s["exp_avg"][r].copy_(net._to_stacked(src["exp_avg"], is_weight))
        s["exp_avg_sq"][r].copy_(net._to_stacked(src["exp_avg_sq"], is_weight))


class EnsembleLearner:
    """R runs stacked in one EnsembleNet with one fused Adam: the `Learner` of a sweep."""

    def __init__(self, net: EnsembleNet, optimizer: torch.optim.Adam, data: list[EvalData]):
        self.net, self.optimizer = net, optimizer
        self.m_regular = torch.stack([d.m_regular for d in data])
        self.eval_inputs = [torch.stack([getattr(d, k) for d in data]) for k in ("m_t", "s_t", "m_t1", "s_t1")]

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]]) -> torch.Tensor:
        device = self.m_regular.device
        m_t, s_t, m_t1, s_t1 = (torch.stack([b[k] for b in batches]).to(device) for k in range(4))
        per_run = (self.net(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=2).mean(dim=1)  # (R,): each run's own loss
        self.optimizer.zero_grad(set_to_none=True)
        per_run.sum().backward()  # parameters are disjoint: each run gets exactly its own gradient
        self.optimizer.step()
        return per_run.detach()

    @torch.no_grad()
    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        h_all = self.net.encode(self.m_regular).double().cpu().numpy()
        pred = self.net(*self.eval_inputs[:3])
        losses = (pred - self.eval_inputs[3]).pow(2).sum(dim=2).mean(dim=1).cpu().numpy()
        pred = pred[:, :N_PREDICTIONS].cpu().numpy()
        return losses, list(h_all), list(pred)

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        return {"model": self.net.run_state(r), "optimizer": _adam_state_of_run(self.net, self.optimizer, r, lr)}

    def load(self, r: int, checkpoint: dict[str, Any]) -> None:
        self.net.load_run(r, checkpoint["model"])
        _load_adam_state(self.net, self.optimizer, r, checkpoint["optimizer"])


# What runs of one ensemble must share: the model's shape and the schedule the loop applies to all.
SHARED = (
    "steps",
    "batch_size",
    "n_h",
    "encoder_layers",
    "predictor_layers",
    "lr_start",
    "lr_end",
    "lr_decay_steps",
    "eval_every",
    "device",
)


def _check_compatible(cfgs: list[TrainConfig]) -> None:
    first = cfgs[0].to_dict()
    for cfg in cfgs[1:]:
        other = cfg.to_dict()
        diff = [k for k in SHARED if other[k] != first[k]]
        if diff:
            raise SmspaceError(f"runs of one ensemble must share {', '.join(diff)}")


def train_ensemble(runs: list[RunDir], resume: bool = False, threads: int = 1, progress: bool = True) -> None:
    """Train runs together to their configured steps: from scratch, or (resume) from their checkpoints."""
    torch.set_num_threads(threads)
    device = resolve_device(runs[0].config.device)
    try:
        for run in runs:
            run.claim()  # before anything is recorded: a run another process trains is left untouched
        _train_claimed(runs, resume, device, progress)
    finally:
        for run in runs:
            run.release()  # the claims end with the training, however it ends


def _train_claimed(runs: list[RunDir], resume: bool, device: torch.device, progress: bool) -> None:
    with recorded_outcome(runs):
        members = [open_member(run, run.config, device) for run in runs]
        _check_compatible([m.cfg for m in members])
        manifests = [m.dataset.manifest for m in members]
        n_motor, shape = manifests[0].n_motor, manifests[0].sensor_shape
        if any(mf.n_motor != n_motor or mf.sensor_shape != shape for mf in manifests):
            raise SmspaceError("runs of one ensemble must have datasets of the same setup")
        n_sensor = int(np.prod(shape))
        cfg0 = members[0].cfg
        check_resources(cfg0, manifests[0], runs=len(runs))
        net = EnsembleNet(len(runs), n_motor, n_sensor, cfg0.n_h, cfg0.encoder_layers, cfg0.predictor_layers).to(device)
        opt = torch.optim.Adam(net.parameters(), lr=cfg0.lr_start, betas=(0.9, 0.999), eps=1e-8, fused=True)
        learner = EnsembleLearner(net, opt, [m.data for m in members])
        if resume:
            step = resume_members(learner, members, device)
        else:
            step = 0
            for r, m in enumerate(members):
                net.load_run(r, build(m.cfg, n_motor, n_sensor, device)[0].state_dict())  # the very init `fit` draws
        train(learner, members, step, progress)
