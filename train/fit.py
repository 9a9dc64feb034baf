"""`smtrain fit`: one run of the sensorimotor predictive network (docs/MODEL.md §3).

Evaluates at step 0 and every `eval_every` steps and checkpoints right after, so `--resume`
continues from the last evaluation and ends bit-identical to an uninterrupted run on the CPU.
The loop itself is `train.loop`; this file is the lone model behind it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel

from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.lake.store import within
from smspace.train.config import TrainConfig, check_resources
from smspace.train.contract import check_model
from smspace.train.distributed import SINGLE, Ranks, peer_errors, per_rank_batch, ranks_agree
from smspace.train.evaluation import N_PREDICTIONS, EvalData
from smspace.train.loop import (
    TrainingFailed,
    open_member,
    recorded_outcome,
    resolve_device,
    resume_members,
    run_dataset,
    train,
)
from smspace.train.model import build_model, prediction_loss
from smspace.train.precision import compiled, step_loss
from smspace.train.run_dir import CHECKPOINT, RunDir
from smspace.train.terms import resumed

__all__ = ["FitPlan", "SingleLearner", "TrainingFailed", "build", "fit", "plan_fit", "resolve_device"]
RUNS = "runs"  # where a run goes without --out: runs/<dataset>-nh<N>-seed<S>


@dataclass(frozen=True)
class FitPlan:
    """A checked fit: what to train, where, and what changed (said once, by rank 0)."""

    cfg: TrainConfig
    where: str
    resume: bool
    overwrite: bool = False
    change: str | None = None  # an extension of a resumed run (train/terms.py, rule 3)

    def start(self) -> RunDir:
        """Create the run folder, or record the extension of a resumed one (rank 0 alone)."""
        if not self.resume:
            return RunDir.create(self.where, self.cfg, self.overwrite)
        run = RunDir.open(self.where)
        if self.change is not None:
            run.write_config(self.cfg)
        return run


def plan_fit(
    template: TrainConfig,
    dataset: str | None,
    lake: str | None,
    out: str | None,
    resume: str | None,
    overwrite: bool,
    given: list[str],
    world: int,
) -> FitPlan:
    """Every check of `smtrain fit` before anything is written: the same on every rank, and in the
    launcher of --nproc before any rank starts. `given`: the flags on the command line."""
    if resume is not None:
        extra = [name for name in given if name != "--steps"]
        if dataset or extra or overwrite:
            raise SmspaceError(f"--resume continues a run with its own config; drop {' '.join(extra) or 'DATASET'}")
        run = RunDir.open(resume)
        steps = template.steps if "--steps" in given else None
        cfg, change = resumed(run.config, str(run.path), steps, world)
        ds = run_dataset(cfg, str(run.path)).verify()
        manifest = ds.manifest
        cfg = cfg if cfg.encoder_layers else cfg.for_dataset(ds.store, manifest)  # a config built by hand
        check_resources(cfg, manifest)
        check_network(cfg, manifest)
        checkpoint = run.load_checkpoint()
        check_checkpoint(checkpoint, cfg, manifest, f"{run.path}/{CHECKPOINT}")
        run.check_whole(checkpoint)
        return FitPlan(cfg, str(run.path), resume=True, change=change)
    if dataset is None:
        raise SmspaceError("DATASET is required (or --resume RUN_DIR)")
    ds = Dataset.open(dataset, lake).verify()
    cfg = replace(template.for_dataset(ds.store, ds.manifest), world_size=world)
    resolve_device(cfg.device)
    check_resources(cfg, ds.manifest)
    check_network(cfg, ds.manifest)
    per_rank_batch(cfg.batch_size, Ranks(0, world))
    where = out or f"{RUNS}/{cfg.run_name}"
    if within(where, ds.store):  # a run folder inside its dataset's folder would be taken for its files
        raise SmspaceError(f"--out {where} lies inside the dataset it trains on ({ds.store.url}); choose another")
    RunDir.creatable(where, overwrite)
    return FitPlan(cfg, str(where), resume=False, overwrite=overwrite)


def network(cfg: TrainConfig, n_motor: int, n_sensor: int) -> torch.nn.Module:
    """The run's model (cfg.model with its parameters), as its config describes it."""
    return build_model(
        cfg.model, n_motor, n_sensor, cfg.n_h, cfg.encoder_layers, cfg.predictor_layers, cfg.model_params
    )


def check_network(cfg: TrainConfig, manifest) -> None:
    """The run's model holds to its contract on a probe batch (train/contract.py), after the memory
    it needs was found to be there."""
    n_sensor = int(np.prod(manifest.sensor_shape))
    check_model(cfg, manifest.n_motor, n_sensor)


def build(cfg: TrainConfig, n_motor: int, n_sensor: int, device: torch.device):
    """The run's initial weights (drawn from its seed) and its optimiser."""
    torch.manual_seed(cfg.seed)
    model = network(cfg, n_motor, n_sensor).to(device)
    # fused Adam: one kernel for all parameters, 1.5-2x faster steps than the per-tensor loop on a CPU
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr_start, betas=(0.9, 0.999), eps=1e-8, fused=True)
    return model, optimizer


def check_checkpoint(checkpoint: dict[str, Any], cfg: TrainConfig, manifest, where: str) -> int:
    """The step of a checkpoint that belongs to this run's network, or one line saying why not (a
    checkpoint of another run, another N_h, other layers or another model) before anything is
    loaded into a model. A checkpoint of smspace 0.1 (weights stored (out, in)) is converted."""
    n_sensor = int(np.prod(manifest.sensor_shape))
    with torch.device("meta"):  # shapes only: nothing is allocated
        expected = network(cfg, manifest.n_motor, n_sensor)
    shapes = {name: tuple(t.shape) for name, t in expected.state_dict().items()}
    state = checkpoint.get("model") if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict) or not isinstance(checkpoint.get("step"), int):
        raise SmspaceError(f"{where} is not a smspace checkpoint (no model or step); it was not loaded")
    if LAYOUT not in checkpoint:
        _upgrade(checkpoint, shapes)
    got = {name: tuple(t.shape) for name, t in state.items() if isinstance(t, torch.Tensor)}
    if got != shapes:
        name = next((n for n in shapes if got.get(n) != shapes[n]), None) or next(n for n in got if n not in shapes)
        raise SmspaceError(
            f"{where} holds another network than this run's config ({name}: {got.get(name)} in the checkpoint, "
            f"{shapes.get(name)} for model {cfg.model}, N_h {cfg.n_h} and layers "
            f"{cfg.encoder_layers}/{cfg.predictor_layers}); it belongs to another run and was not loaded"
        )
    if not 0 <= checkpoint["step"] <= cfg.steps:
        raise SmspaceError(f"{where} is at step {checkpoint['step']}, outside this run's 0..{cfg.steps}")
    return checkpoint["step"]


LAYOUT = "layout"  # in checkpoints: "in-out", how dense weights are stored (absent: smspace 0.1's (out, in))


def _upgrade(checkpoint: dict[str, Any], shapes: dict[str, tuple[int, ...]]) -> None:
    """Weights smspace 0.1 stored (out, in), and their Adam moments, transposed to (in, out)."""
    state = checkpoint["model"]
    names = list(state)
    flipped = [
        n
        for n in names
        if state[n].dim() == 2 and tuple(state[n].shape[::-1]) == shapes.get(n) != tuple(state[n].shape)
    ]
    for n in flipped:
        state[n] = state[n].t().contiguous()
    moments = checkpoint.get("optimizer", {}).get("state", {})
    for i, n in enumerate(names):
        if n in flipped and i in moments:
            for key in ("exp_avg", "exp_avg_sq"):
                moments[i][key] = moments[i][key].t().contiguous()
    checkpoint[LAYOUT] = "in-out"


class SingleLearner:
    """One model and its Adam: the `Learner` of a lone run (under DDP, of one rank)."""

    def __init__(
        self,
        model: torch.nn.Module,
        optimizer: torch.optim.Adam,
        data: EvalData,
        ranks: Ranks = SINGLE,
        precision: str = "fp32",
        compile: bool = False,
    ):
        self.model, self.optimizer, self.data, self.ranks = model, optimizer, data, ranks
        self.precision, self.compile = precision, compile
        self._trained: torch.nn.Module | None = None
        self._loss: Callable | None = None

    def _training_model(self) -> torch.nn.Module:
        """The model the steps run through: wrapped in DDP (gradients averaged over the ranks) when
        there are several, built at the first step, after any checkpoint was loaded."""
        if self._trained is None:
            self._trained = DistributedDataParallel(self.model) if self.ranks.distributed else self.model
        return self._trained

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def _step_loss(self) -> Callable:
        """The forward pass and loss of a step, in the run's precision, compiled if asked."""
        if self._loss is None:
            loss = step_loss(self._training_model(), self.precision, self.data.m_regular.device)
            self._loss = compiled(loss, self.compile)
        return self._loss

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]]) -> torch.Tensor:
        device = self.data.m_regular.device
        m_t, s_t, m_t1, s_t1 = (x.to(device, non_blocking=True) for x in batches[0])
        loss = self._step_loss()(m_t, s_t, m_t1, s_t1)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.detach().reshape(1)

    @torch.no_grad()
    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        d = self.data
        h = self.model.encode(d.m_regular).double().cpu().numpy()
        pred = self.model(d.m_t, d.s_t, d.m_t1)
        loss = float(prediction_loss(pred, d.s_t1))
        return np.array([loss]), [h], [pred[:N_PREDICTIONS].cpu().numpy()]

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        return {"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load(self, r: int, checkpoint: dict[str, Any]) -> None:
        self.model.load_state_dict(checkpoint["model"])
        self.optimizer.load_state_dict(checkpoint["optimizer"])


def fit(cfg: TrainConfig, run: RunDir, resume: bool = False, ranks: Ranks = SINGLE) -> dict[str, Any] | None:
    """Train (or resume) one run; returns its last metrics row (on rank 0; None on the others)."""
    torch.set_num_threads(cfg.threads)  # 2 cores: oversubscribed threads made steps 10-40x slower
    device = resolve_device(cfg.device)
    if ranks.primary:
        run.claim()  # before anything is recorded: a run another process trains is left untouched
    try:
        if ranks.primary:
            run.record_session(cfg.device, cfg.threads)
        return _fit_claimed(cfg, run, resume, ranks, device)
    finally:
        run.release()  # the lock ends with the training, not whenever the RunDir is collected


def _fit_claimed(cfg: TrainConfig, run: RunDir, resume: bool, ranks: Ranks, device) -> dict[str, Any] | None:
    with recorded_outcome([run] if ranks.primary else []):
        member = open_member(run, cfg, device, ranks)
        manifest = member.dataset.manifest
        cfg = member.cfg
        model, optimizer = build(cfg, manifest.n_motor, int(np.prod(manifest.sensor_shape)), device)
        learner = SingleLearner(model, optimizer, member.data, ranks, cfg.precision, cfg.compile)
        step = resume_members(learner, [member], device, ranks) if resume else 0
        with peer_errors(ranks):
            train(learner, [member], step, ranks=ranks, synced=lambda: ranks_agree(model, ranks))
    return member.rows[-1] if ranks.primary else None
