"""The training engine: everything between a run's config and its trained weights, in the order
it happens. (1) the network and its optimiser, (2) the checkpoint format, (3) the training step,
(4) the two learners (one model, DDP-wrapped or not; R models stacked into one), (5) the loop:
the learning-rate schedule, per-run loss, NaN handling, and an evaluation at step 0 and every
`eval_every` steps, which leaves through sinks.

It imports nothing of run folders, the lake or launchers: what a run is trained on comes in as
`Member`s (a stream of batches and an evaluation set), and what it produces goes out through
`Sink`s (train/fit.py writes the run folder; a W&B or MLflow logger would be one more sink).
Resuming is loading checkpoints the caller read (`resume`).
"""

from __future__ import annotations

import functools
import math
import random
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel

from smspace.common.errors import SmspaceError
from smspace.common.limits import STEP_LIMIT_ENV, step_limit_s, time_limit
from smspace.common.progress import Progress
from smspace.metrics import spatial_scores
from smspace.metrics.spatial import DegenerateRepresentation, check_representation
from smspace.train.config import TrainConfig
from smspace.train.contract import check_outputs
from smspace.train.distributed import SINGLE, Ranks, lost_a_peer, mean_over_ranks, ranks_agree
from smspace.train.ensemble import Stacked, adam_state_of_run, load_adam_state
from smspace.train.model import (
    Method,
    as_windows,
    build_model,
    has_after_step,
    has_objective,
    model_label,
    noise_dim,
    prediction_loss,
    reads_windows,
)
from smspace.train.precision import autocast, compiled
from smspace.train.worker_batches import worker_batches

# --- 1. the network and its optimiser -------------------------------------------------------------


def resolve_device(name: str) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise SmspaceError(f"--device cuda: no CUDA GPU is usable here (torch {torch.__version__})")
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise SmspaceError(f"unknown --device {name!r} (cpu or cuda)")
    return torch.device(name)


def network(cfg: TrainConfig, n_motor: int, n_sensor: int) -> torch.nn.Module:
    """The run's model (cfg.model with its parameters), as its config describes it."""
    return build_model(
        cfg.model, n_motor, n_sensor, cfg.n_h, cfg.encoder_layers, cfg.predictor_layers, cfg.model_params
    )


def adam(parameters: Iterable[torch.Tensor], lr: float) -> torch.optim.Adam:
    """The optimiser of every run (docs/MODEL.md §3). Fused: one kernel for all parameters, 1.5-2x
    faster steps than the per-tensor loop on a CPU."""
    return torch.optim.Adam(parameters, lr=lr, betas=(0.9, 0.999), eps=1e-8, fused=True)


def build(cfg: TrainConfig, n_motor: int, n_sensor: int, device: torch.device):
    """The run's initial weights (drawn from its seed) and its optimiser: a run stacked in an
    ensemble starts from the very weights its lone `fit` draws. numpy's and Python's global
    generators are seeded too, so that a model drawing from them (np.random, random) gives the same
    bytes for the same command and seed; an ensemble's runs share them, in the order they are built."""
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed % 2**32)
    random.seed(cfg.seed)
    model = network(cfg, n_motor, n_sensor).to(device)
    return model, adam(model.parameters(), cfg.lr_start)


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear from lr_start to lr_end over lr_decay_steps, then constant (docs/MODEL.md §3)."""
    frac = min(step, cfg.lr_decay_steps) / cfg.lr_decay_steps
    return cfg.lr_start + (cfg.lr_end - cfg.lr_start) * frac


# --- 2. the checkpoint format ---------------------------------------------------------------------
# {"model": the lone model's state_dict, "optimizer": its Adam state_dict, "stream": the loader's
# position, "step", "elapsed_s", LAYOUT: "in-out"}: the same for a lone run and for each run of an
# ensemble, so that either continues the other.

LAYOUT = "layout"  # "in-out": dense weights stored (in, out); absent in checkpoints of the first layout (out, in)


def check_checkpoint(checkpoint: dict[str, Any], cfg: TrainConfig, n_motor: int, n_sensor: int, where: str) -> int:
    """The step of a checkpoint that belongs to this run's network, or one line saying why not (a
    checkpoint of another run, another N_h, other layers or another model) before anything is
    loaded into a model. A checkpoint in the first layout is converted."""
    with torch.device("meta"):  # shapes only: nothing is allocated
        expected = network(cfg, n_motor, n_sensor)
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


def _upgrade(checkpoint: dict[str, Any], shapes: dict[str, tuple[int, ...]]) -> None:
    """Weights stored (out, in), and their Adam moments, transposed to (in, out)."""
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


# --- 3. the training step -------------------------------------------------------------------------

Loss = Callable[..., torch.Tensor]


def step_loss(
    forward: Callable[..., torch.Tensor], precision: str, device: torch.device, objective: bool = False
) -> Loss:
    """The forward pass and loss of a training step in `precision` (the loss itself in fp32): for a
    lone model and a stacked ensemble alike (whose losses are each run's own, (R,)). `objective`:
    `forward` is the model's own objective, given s_t1 too (train/model.py, has_objective)."""

    def loss(m_t: torch.Tensor, s_t: torch.Tensor, m_t1: torch.Tensor, s_t1: torch.Tensor, *noise) -> torch.Tensor:
        with autocast(precision, device):
            if objective:
                return forward(m_t, s_t, m_t1, s_t1, *noise).float()
            pred = forward(m_t, s_t, m_t1)
        return prediction_loss(pred.float(), s_t1)

    return loss


def step_noise(seeds: Sequence[int], step: int, rank: int, rows: int, dim: int, device: torch.device) -> torch.Tensor:
    """(R, rows, dim) standard normals, run r's for this step (train/model.py, noise_dim): drawn on
    the CPU by a generator seeded from (run seed, rank, step) alone, so a run's noise is the same
    alone or stacked, on any device, and after a resume, with no generator state to checkpoint;
    each rank of a DDP run, training on its own rows, draws its own."""
    draws = []
    for seed in seeds:
        entropy = np.random.SeedSequence([seed % 2**63, rank, step]).generate_state(1, np.uint64)[0]
        generator = torch.Generator().manual_seed(int(entropy))
        draws.append(torch.randn(rows, dim, generator=generator))
    return torch.stack(draws).to(device)


N_PREDICTIONS = 16  # predicted vs true s_t1 kept per evaluation, for viewers and reports


@dataclass
class EvalData:
    """What every evaluation looks at: the regular sampling and a fixed set of transitions."""

    m_regular: torch.Tensor  # normalised with the dataset's motor statistics
    p_regular: np.ndarray
    m_t: torch.Tensor
    s_t: torch.Tensor
    m_t1: torch.Tensor
    s_t1: torch.Tensor


def scores_row(h: np.ndarray, p: np.ndarray, eval_loss: float) -> dict[str, float]:
    scores = spatial_scores(h, p)
    return {"eval_loss": eval_loss, "d_topo": scores.d_topo, "d_metric": scores.d_metric}


# --- 4. the learners ------------------------------------------------------------------------------


class Learner(Protocol):
    """R runs' models and optimisers; run r sees only its own batches and gradients."""

    compile: bool  # whether the steps go through torch.compile (the session's decision)

    def set_lr(self, lr: float) -> None: ...

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]], step: int) -> torch.Tensor:
        """Optimiser step `step` (1, 2, …) on batch r for run r, then each model's after_step();
        returns the (R,) losses, detached."""
        ...

    def check_batch(self, batches: Sequence[tuple[torch.Tensor, ...]], label: str) -> None:
        """The shapes the model gives on these real batches (train/contract.py, check_outputs)."""
        ...

    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Per run: loss on its evaluation set, h of its regular sampling, its first predictions."""
        ...

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        """Run r's {"model", "optimizer"} state in the lone run's checkpoint format."""
        ...

    def load(self, r: int, checkpoint: dict[str, Any]) -> None: ...

    def weights_agree(self) -> bool:
        """Whether every rank holds the same weights (always, without DDP)."""
        ...


class SingleLearner:
    """One model and its Adam: the learner of a lone run (under DDP, of one rank)."""

    def __init__(
        self,
        model: torch.nn.Module,
        optimizer: torch.optim.Adam,
        data: EvalData,
        ranks: Ranks = SINGLE,
        precision: str = "fp32",
        compile: bool = False,
        seed: int = 0,
    ):
        self.model, self.optimizer, self.data, self.ranks = model, optimizer, data, ranks
        self.precision, self.compile, self.seed = precision, compile, seed
        self.noise_dim, self.after_step = noise_dim(model), has_after_step(model)
        self.windows = reads_windows(model)
        self._trained: torch.nn.Module | None = None
        self._loss: Callable | None = None

    def _training_model(self) -> torch.nn.Module:
        """The model the steps run through: wrapped in DDP (gradients averaged over the ranks) when
        there are several, built at the first step, after any checkpoint was loaded."""
        if self._trained is None:
            trained = Method(self.model, "objective") if has_objective(self.model) else self.model
            self._trained = DistributedDataParallel(trained) if self.ranks.distributed else trained
        return self._trained

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def _step_loss(self) -> Callable:
        """The forward pass and loss of a step, in the run's precision, compiled if decided."""
        if self._loss is None:
            device, own = self.data.m_regular.device, has_objective(self.model)
            loss = step_loss(self._training_model(), self.precision, device, own)
            self._loss = compiled(loss, self.compile)
        return self._loss

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]], step: int) -> torch.Tensor:
        device = self.data.m_regular.device
        m_t, s_t, m_t1, s_t1 = (x.to(device, non_blocking=True) for x in batches[0])
        if self.windows:
            m_t, s_t, m_t1, s_t1 = (as_windows(x, 1) for x in (m_t, s_t, m_t1, s_t1))
        noise = []
        if self.noise_dim:
            noise = [step_noise([self.seed], step, self.ranks.rank, len(m_t), self.noise_dim, device)[0]]
        loss = self._step_loss()(m_t, s_t, m_t1, s_t1, *noise)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        if self.after_step:
            with torch.no_grad():
                self.model.after_step()
        return loss.detach().reshape(1)

    @torch.no_grad()
    def check_batch(self, batches: Sequence[tuple[torch.Tensor, ...]], label: str) -> None:
        device = self.data.m_regular.device
        m_t, s_t, m_t1, s_t1 = (x.to(device) for x in batches[0])
        if self.windows:  # the objective reads the windows, forward the first step of each
            m_t, s_t, m_t1, s_t1 = (as_windows(x, 1) for x in (m_t, s_t, m_t1, s_t1))
        first = [x[:, 0] for x in (m_t, s_t, m_t1, s_t1)] if self.windows else [m_t, s_t, m_t1, s_t1]
        pred = self.model(*first[:3])
        noise = [m_t.new_zeros(len(m_t), self.noise_dim)] if self.noise_dim else []
        own = has_objective(self.model)
        loss = self.model.objective(m_t, s_t, m_t1, s_t1, *noise) if own else prediction_loss(pred, s_t1)
        check_outputs(label, loss, pred, first[3], stacked=False)

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

    def weights_agree(self) -> bool:
        return ranks_agree(self.model, self.ranks)


class EnsembleLearner:
    """R runs' models stacked (train/ensemble.py) with one fused Adam: the learner of a sweep.
    Each run's initial weights are the very ones its lone `fit` draws from its seed."""

    def __init__(
        self, cfgs: list[TrainConfig], n_motor: int, n_sensor: int, data: list[EvalData], device, compile: bool = False
    ):
        self.stacked = Stacked([build(cfg, n_motor, n_sensor, device)[0] for cfg in cfgs])
        self.optimizer = adam(self.stacked.parameters(), cfgs[0].lr_start)
        self.seeds, self.noise_dim = [cfg.seed for cfg in cfgs], noise_dim(self.stacked.model)
        self.windows = reads_windows(self.stacked.model)
        own = has_objective(self.stacked.model)
        forward = self.stacked.objective if own else self.stacked.forward
        loss = step_loss(forward, cfgs[0].precision, data[0].m_regular.device, own)
        self.compile = compile
        self._loss = compiled(loss, compile)
        self.m_regular = torch.stack([d.m_regular for d in data])
        self.eval_inputs = [torch.stack([getattr(d, k) for d in data]) for k in ("m_t", "s_t", "m_t1", "s_t1")]

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]], step: int) -> torch.Tensor:
        device = self.m_regular.device
        m_t, s_t, m_t1, s_t1 = (torch.stack([b[k] for b in batches]).to(device) for k in range(4))
        if self.windows:
            m_t, s_t, m_t1, s_t1 = (as_windows(x, 2) for x in (m_t, s_t, m_t1, s_t1))
        noise = [step_noise(self.seeds, step, 0, m_t.shape[1], self.noise_dim, device)] if self.noise_dim else []
        per_run = self._loss(m_t, s_t, m_t1, s_t1, *noise)
        self.optimizer.zero_grad(set_to_none=True)
        per_run.sum().backward()  # parameters are disjoint: each run gets exactly its own gradient
        self.optimizer.step()
        self.stacked.after_step()
        return per_run.detach()

    @torch.no_grad()
    def check_batch(self, batches: Sequence[tuple[torch.Tensor, ...]], label: str) -> None:
        m_t, s_t, m_t1, s_t1 = (torch.stack([b[k] for b in batches]).to(self.m_regular.device) for k in range(4))
        if self.windows:  # the objective reads the windows, forward the first step of each
            m_t, s_t, m_t1, s_t1 = (as_windows(x, 2) for x in (m_t, s_t, m_t1, s_t1))
        first = [x[:, :, 0] for x in (m_t, s_t, m_t1, s_t1)] if self.windows else [m_t, s_t, m_t1, s_t1]
        pred = self.stacked.forward(*first[:3])
        own = has_objective(self.stacked.model)
        noise = [m_t.new_zeros(*m_t.shape[:2], self.noise_dim)] if self.noise_dim else []
        loss = self.stacked.objective(m_t, s_t, m_t1, s_t1, *noise) if own else prediction_loss(pred, s_t1)
        check_outputs(label, loss, pred, first[3], stacked=True)

    @torch.no_grad()
    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        h_all = _in_row_chunks(self.stacked.encode, self.m_regular).double().cpu().numpy()
        pred = _in_row_chunks(self.stacked.forward, *self.eval_inputs[:3])
        losses = prediction_loss(pred, self.eval_inputs[3]).cpu().numpy()
        return losses, list(h_all), list(pred[:, :N_PREDICTIONS].cpu().numpy())

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        return {
            "model": self.stacked.run_state(r),
            "optimizer": adam_state_of_run(self.stacked, self.optimizer, r, lr),
        }

    def load(self, r: int, checkpoint: dict[str, Any]) -> None:
        self.stacked.load_run(r, checkpoint["model"])
        load_adam_state(self.stacked, self.optimizer, r, checkpoint["optimizer"])

    def weights_agree(self) -> bool:
        return True


EVAL_ROWS = 256  # rows per evaluation forward: 30 runs x 4096 rows at once left the caches, 2x slower


def _in_row_chunks(fn: Callable[..., torch.Tensor], *stacked: torch.Tensor) -> torch.Tensor:
    """fn over (R, rows, ...) inputs, EVAL_ROWS rows at a time (every row is computed alone)."""
    rows = stacked[0].shape[1]
    return torch.cat([fn(*(x[:, i : i + EVAL_ROWS] for x in stacked)) for i in range(0, rows, EVAL_ROWS)], dim=1)


# --- 5. the loop ----------------------------------------------------------------------------------

TICK_S = 1.0  # how often on_step hears of the step


class TrainingFailed(SmspaceError):
    """Training itself went wrong (NaN loss); the last good checkpoint is kept."""

    exit_code = 1


@dataclass
class Member:
    """One run being trained: its name (for messages), config, stream of batches (with its
    position: state_dict / load_state_dict / batches_consumed), evaluation set, and metrics so far."""

    name: str
    cfg: TrainConfig
    stream: Any
    data: EvalData
    rows: list[dict[str, Any]] = field(default_factory=list)
    elapsed: float = 0.0


@dataclass
class Evaluation:
    """What one evaluation of run r leaves: its metrics so far (this step's row last), h of the
    regular sampling with the positions, the first predictions (and, at step 0, their targets),
    and the checkpoint state."""

    r: int
    rows: list[dict[str, Any]]
    h: np.ndarray
    p: np.ndarray
    predictions: np.ndarray
    true: np.ndarray | None
    state: dict[str, Any]

    @property
    def step(self) -> int:
        return self.rows[-1]["step"]


class Sink(Protocol):
    """Where evaluations go (a run folder, a logger), in the order they happen."""

    def on_evaluation(self, evaluation: Evaluation) -> None: ...

    def on_finish(self, step: int, message: str) -> None: ...


def resume(learner: Learner, members: list[Member], checkpoints: list[dict[str, Any]], shape: tuple[int, int]) -> int:
    """Load each run's checkpoint (all of one step, read by the caller), checked against its
    network first; returns that step. `shape`: (n_motor, n_sensor) of the runs' datasets."""
    steps = {int(c["step"]) for c in checkpoints}
    if len(steps) != 1:
        raise SmspaceError(f"runs trained together must resume at one step, not {sorted(steps)}")
    for r, (m, checkpoint) in enumerate(zip(members, checkpoints, strict=True)):
        check_checkpoint(checkpoint, m.cfg, *shape, f"{m.name}/checkpoint.pt")
        learner.load(r, checkpoint)
        m.stream.load_state_dict(checkpoint["stream"])
        m.elapsed = float(checkpoint["elapsed_s"])
    return steps.pop()


def train(
    learner: Learner,
    members: list[Member],
    step: int,
    sinks: Sequence[Sink] = (),
    progress: bool = True,
    ranks: Ranks = SINGLE,
    on_step: Callable[[int], None] | None = None,
) -> None:
    """Train every member from `step` (0, or where `resume` left them) to cfg.steps. Under DDP
    every rank steps, rank 0 alone evaluates and its sinks write, and at each evaluation all ranks
    check that they hold identical weights. `on_step`: told the step about every second (a sweep's
    progress across processes)."""
    cfg = members[0].cfg  # the schedule is shared: ensembles check that their runs agree on it
    count = len(members)
    device = members[0].data.m_regular.device

    def record(step: int, train_loss: np.ndarray, wall: float) -> None:
        if not learner.weights_agree():
            raise TrainingFailed(f"the {ranks.world} ranks hold different weights at step {step}; stopped")
        if not ranks.primary:
            return
        losses, hs, preds = learner.evaluate()
        lr = learning_rate(cfg, step)
        for r, h in enumerate(hs):
            try:
                check_representation(h, f"h of {members[r].name.rsplit('/', 1)[-1]} at step {step}")
            except DegenerateRepresentation as e:
                last = members[r].rows[-1]["step"] if members[r].rows else None
                kept = f"the checkpoint of step {last} is kept" if last is not None else "no checkpoint was written"
                raise TrainingFailed(f"{e}; no score is computed from it: stopped, {kept}") from None
        for r, m in enumerate(members):
            m.elapsed += wall / count
            row = {
                "step": step,
                "lr": lr,
                "train_loss": float(train_loss[r]),
                **scores_row(hs[r], m.data.p_regular, float(losses[r])),
                "elapsed_s": m.elapsed,
            }
            state = {**learner.state_of(r, lr), "stream": m.stream.state_dict(), "step": step, "elapsed_s": m.elapsed}
            state[LAYOUT] = "in-out"
            m.rows.append(row)
            true = m.data.s_t1[:N_PREDICTIONS].cpu().numpy() if step == 0 else None  # the targets, once
            for sink in sinks:
                sink.on_evaluation(Evaluation(r, m.rows, hs[r], m.data.p_regular, preds[r], true, state))

    def diverged(at: int, losses: np.ndarray) -> TrainingFailed:
        bad = ", ".join(members[r].name.rsplit("/", 1)[-1] for r in np.flatnonzero(~np.isfinite(losses)))
        last = members[0].rows[-1]["step"] if members[0].rows else 0
        return TrainingFailed(
            f"loss became NaN or inf at step {at} in {bad}; stopped, the checkpoint of step {last} is kept"
        )

    if step == 0 and not any(m.rows for m in members):  # resumed from a step-0 checkpoint: recorded already
        record(0, np.full(count, math.nan), 0.0)
    batches = [worker_batches(m.stream, m.cfg.loader_workers) for m in members]  # train/worker_batches.py
    check_each_step = device.type == "cpu"  # .item() is free on a CPU, a sync on a GPU
    loss_sum = torch.zeros(count, dtype=torch.float32, device=device)
    loss_count = 0
    desc = "training" if count == 1 else f"ensemble of {count}"
    bar = Progress(desc, cfg.steps, "step", initial=step, enabled=progress and ranks.primary)
    last_tick = time.monotonic()
    compile_note: dict[str, str] = {}
    label, first, limit_s = model_label(cfg.model), True, step_limit_s()
    try:
        t0 = time.perf_counter()
        while step < cfg.steps:
            learner.set_lr(learning_rate(cfg, step))
            started = time.perf_counter()
            batch = [_next_batch(b) for b in batches]
            last = members[0].rows[-1]["step"] if members[0].rows else 0
            try:
                with time_limit(limit_s, functools.partial(_too_long, label, step + 1, limit_s, last)):
                    if first or (step + 1) % cfg.eval_every == 0 or step + 1 == cfg.steps:
                        learner.check_batch(batch, label)  # the real batches, not only the contract's probe sizes
                        first = False
                    losses = mean_over_ranks(learner.train_step(batch, step + 1), ranks)
            except SmspaceError:
                raise
            except Exception as e:  # a model's step (a loss detached late, memory): one line
                if ranks.distributed and lost_a_peer(e):
                    raise  # another rank is gone: train/distributed.peer_errors names it
                raise TrainingFailed(
                    f"{label} failed in training step {step + 1} ({type(e).__name__}: {_first_line(e)}); "
                    f"stopped, the checkpoint of step {last} is kept"
                ) from e
            if learner.compile and not compile_note:  # the first step of a session pays for compilation
                compile_note = {"compiled in": f"{time.perf_counter() - started:.1f} s"}
                bar.set_postfix(**compile_note)
            if check_each_step and not bool(torch.isfinite(losses).all()):
                raise diverged(step, losses.numpy())
            step += 1
            for m in members:
                m.stream.batches_consumed = step
            loss_sum += losses
            loss_count += 1
            bar.update()
            if on_step is not None and time.monotonic() - last_tick >= TICK_S:
                on_step(step)
                last_tick = time.monotonic()
            if step % cfg.eval_every == 0 or step == cfg.steps:
                train_loss = loss_sum.double().cpu().numpy() / loss_count
                if not np.isfinite(train_loss).all():
                    raise diverged(step, train_loss)
                record(step, train_loss, time.perf_counter() - t0)
                t0 = time.perf_counter()
                loss_sum.zero_()
                loss_count = 0
                if ranks.primary:
                    bar.set_postfix(**compile_note, **_summary([m.rows[-1] for m in members]))
        if on_step is not None:
            on_step(step)
    finally:
        bar.close()
    if ranks.primary:
        message = f"{ranks.world} ranks, identical weights at every evaluation" if ranks.distributed else ""
        for sink in sinks:
            sink.on_finish(step, message)


def _summary(rows: list[dict[str, Any]]) -> dict[str, str]:
    """The last evaluation for a progress line: the run's values, or an ensemble's medians."""
    prefix = "" if len(rows) == 1 else "median "
    shown = {"loss": ("eval_loss", ".4g"), "D_topo": ("d_topo", ".3g"), "D_metric": ("d_metric", ".3g")}
    return {prefix + name: format(float(np.median([r[key] for r in rows])), fmt) for name, (key, fmt) in shown.items()}


def _too_long(label: str, step: int, limit_s: float, last: int) -> TrainingFailed:
    return TrainingFailed(
        f"{label}: training step {step} took more than {limit_s:g} s (${STEP_LIMIT_ENV} bounds a step); "
        f"stopped, the checkpoint of step {last} is kept"
    )


def _first_line(e: BaseException) -> str:
    lines = [line for line in str(e).splitlines() if line.strip()]
    return lines[0][:300] if lines else "no message"


def _next_batch(batches) -> tuple[torch.Tensor, ...]:
    try:
        return next(batches)
    except SmspaceError as e:
        # a DataLoader worker's error comes back with its traceback in the message: keep its own line
        lines = [ln for ln in str(e).splitlines() if ln.strip()]
        raise type(e)(lines[-1].split(": ", 1)[-1] if len(lines) > 1 else str(e)) from e
