"""Many independent runs trained at once as one vectorised model (batched matmuls over a runs
dimension). Run r keeps its own dataset stream, seed, initial weights and Adam state, so it is
mathematically the run `smtrain fit` would train alone; only the summation order of the matmuls
differs. Every run writes the same folder as `smtrain fit`, checkpoint format included.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from datagen.errors import SmspaceError
from datagen.lake.dataset import Dataset
from train.config import TrainConfig, learning_rate
from train.evaluation import N_PREDICTIONS, EvalData, scores_row, write_evaluation
from train.fit import TrainingFailed, build, resolve_device
from train.loader import TransitionStream
from train.model import SensorimotorNet, default_encoder_layers
from train.run_dir import RunDir


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


@dataclass
class Member:
    """One run of the ensemble: its folder, config, data and evaluation set."""

    run: RunDir
    cfg: TrainConfig
    stream: TransitionStream
    data: EvalData
    rows: list[dict[str, Any]]
    elapsed: float = 0.0


def _check_compatible(cfgs: list[TrainConfig]) -> None:
    keys = (
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
    first = cfgs[0].to_dict()
    for cfg in cfgs[1:]:
        other = cfg.to_dict()
        diff = [k for k in keys if other[k] != first[k]]
        if diff:
            raise SmspaceError(f"runs of one ensemble must share {', '.join(diff)}")


def train_ensemble(runs: list[RunDir], resume_step: int = 0, threads: int = 1, progress: bool = True) -> None:
    """Train runs (all at `resume_step`: 0 for new runs) together to their configured steps."""
    cfgs = [r.config for r in runs]
    _check_compatible(cfgs)
    cfg0 = cfgs[0]
    torch.set_num_threads(threads)
    device = resolve_device(cfg0.device)
    datasets = [Dataset(c.dataset) for c in cfgs]
    n_motor, shape = datasets[0].manifest.n_motor, datasets[0].manifest.sensor_shape
    if any(d.manifest.n_motor != n_motor or d.manifest.sensor_shape != shape for d in datasets):
        raise SmspaceError("runs of one ensemble must have datasets of the same setup")
    n_sensor = int(np.prod(shape))
    count = len(runs)
    enc = list(cfg0.encoder_layers or default_encoder_layers(n_motor))
    net = EnsembleNet(count, n_motor, n_sensor, cfg0.n_h, enc, list(cfg0.predictor_layers)).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg0.lr_start, betas=(0.9, 0.999), eps=1e-8, fused=True)
    members = []
    for r, (run, cfg, ds) in enumerate(zip(runs, cfgs, datasets, strict=True)):
        stream = TransitionStream(ds, cfg.batch_size, seed=cfg.seed, window=cfg.shuffle_window)
        member = Member(run, cfg, stream, EvalData.load(ds, cfg.eval_transitions, device), [])
        if resume_step:
            ckpt = run.load_checkpoint(str(device))
            if int(ckpt["step"]) != resume_step:
                raise SmspaceError(f"{run.path} is at step {ckpt['step']}, not {resume_step}")
            net.load_run(r, ckpt["model"])
            _load_adam_state(net, opt, r, ckpt["optimizer"])
            stream.load_state_dict(ckpt["stream"])
            member.elapsed = float(ckpt["elapsed_s"])
            member.rows = [row for row in run.metrics() if row["step"] <= resume_step]
            run.truncate_after(resume_step)
        else:
            model: SensorimotorNet = build(cfg, n_motor, n_sensor, device)[0]  # the very init `fit` draws
            net.load_run(r, model.state_dict())
        members.append(member)

    m_reg = torch.stack([m.data.m_regular for m in members])
    eval_inputs = [torch.stack([getattr(m.data, k) for m in members]) for k in ("m_t", "s_t", "m_t1", "s_t1")]

    @torch.no_grad()
    def record(step: int, train_loss: np.ndarray, wall: float) -> None:
        h_all = net.encode(m_reg).double().cpu().numpy()
        pred = net(*eval_inputs[:3])
        losses = (pred - eval_inputs[3]).pow(2).sum(dim=2).mean(dim=1).cpu().numpy()
        pred = pred[:, :N_PREDICTIONS].cpu().numpy()
        lr = learning_rate(cfg0, step)
        for r, m in enumerate(members):
            m.elapsed += wall / count
            row = {
                "step": step,
                "lr": lr,
                "train_loss": float(train_loss[r]),
                **scores_row(h_all[r], m.data.p_regular, float(losses[r])),
                "elapsed_s": m.elapsed,
            }
            checkpoint = {
                "model": net.run_state(r),
                "optimizer": _adam_state_of_run(net, opt, r, lr),
                "stream": m.stream.state_dict(),
                "step": step,
                "elapsed_s": m.elapsed,
            }
            write_evaluation(m.run, m.rows, row, h_all[r], m.data, pred[r], checkpoint)

    step = resume_step
    if step == 0:
        record(0, np.full(count, math.nan), 0.0)
    iterators = [iter(m.stream) for m in members]
    loss_sum = torch.zeros(count, device=device)
    loss_count = 0
    bar = tqdm(
        total=cfg0.steps,
        initial=step,
        unit="step",
        disable=None if progress else True,
        file=sys.stderr,
        desc=f"ensemble of {count}",
    )
    try:
        t0 = time.perf_counter()
        while step < cfg0.steps:
            for group in opt.param_groups:
                group["lr"] = learning_rate(cfg0, step)
            batches = [next(it) for it in iterators]
            m_t, s_t, m_t1, s_t1 = (torch.stack([b[k] for b in batches]).to(device) for k in range(4))
            per_run = (net(m_t, s_t, m_t1) - s_t1).pow(2).sum(dim=2).mean(dim=1)  # (R,): each run's own loss
            opt.zero_grad(set_to_none=True)
            per_run.sum().backward()  # parameters are disjoint: each run gets exactly its own gradient
            opt.step()
            step += 1
            for m in members:
                m.stream.batches_consumed = step
            loss_sum += per_run.detach()
            loss_count += 1
            bar.update()
            if step % cfg0.eval_every == 0 or step == cfg0.steps:
                train_loss = loss_sum.cpu().numpy() / loss_count
                bad = [members[r].run.path.name for r in np.flatnonzero(~np.isfinite(train_loss))]
                if bad:
                    raise TrainingFailed(
                        f"loss became NaN or inf before step {step} in {', '.join(bad)}; "
                        "stopped, the checkpoints of the previous evaluation are kept"
                    )
                record(step, train_loss, time.perf_counter() - t0)
                t0 = time.perf_counter()
                loss_sum.zero_()
                loss_count = 0
    except SmspaceError as e:
        for m in members:
            m.run.set_status("failed", m.rows[-1]["step"] if m.rows else 0, str(e))
        raise
    finally:
        bar.close()
    for m in members:
        m.run.set_status("finished", step)
