"""The one training loop, for a lone run (`smtrain fit`) and for a stacked ensemble (`smtrain sweep`).

It owns what both must do the same way: the learning-rate schedule, per-run loss accumulation,
evaluation at step 0 and every `eval_every` steps (metrics row, h, predictions, then the
checkpoint), NaN handling, status, and resuming from the checkpoints. What differs between a
lone model and a stacked ensemble sits behind `Learner`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch
from torch.utils.data import DataLoader

from smspace.common.bounded import run_within
from smspace.common.errors import SmspaceError
from smspace.common.progress import Progress
from smspace.lake.dataset import Dataset
from smspace.train.config import TrainConfig
from smspace.train.distributed import SINGLE, Ranks, mean_over_ranks, per_rank_batch
from smspace.train.evaluation import N_PREDICTIONS, EvalData, scores_row
from smspace.train.loader import TransitionStream
from smspace.train.run_dir import RunDir

TICK_S = 1.0  # how often on_step hears of the step
LAYOUT = "layout"  # recorded in checkpoints: dense weights stored (in, out) (train/fit.py, _upgrade)


class TrainingFailed(SmspaceError):
    """Training itself went wrong (NaN loss); the last good checkpoint is kept."""

    exit_code = 1


class Learner(Protocol):
    """R runs' models and optimisers; run r sees only its own batches and gradients."""

    def set_lr(self, lr: float) -> None: ...

    def train_step(self, batches: Sequence[tuple[torch.Tensor, ...]]) -> torch.Tensor:
        """One optimiser step on batch r for run r; returns the (R,) losses, detached."""
        ...

    def evaluate(self) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Per run: loss on its evaluation set, h of its regular sampling, its first predictions."""
        ...

    def state_of(self, r: int, lr: float) -> dict[str, Any]:
        """Run r's {"model", "optimizer"} state in the lone run's checkpoint format."""
        ...

    def load(self, r: int, checkpoint: dict[str, Any]) -> None: ...


@dataclass
class Member:
    """One run being trained: its folder, config, data stream, evaluation set and metrics so far."""

    run: RunDir
    cfg: TrainConfig
    dataset: Dataset
    stream: TransitionStream
    data: EvalData
    rows: list[dict[str, Any]] = field(default_factory=list)
    elapsed: float = 0.0


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear from lr_start to lr_end over lr_decay_steps, then constant (docs/MODEL.md §3)."""
    frac = min(step, cfg.lr_decay_steps) / cfg.lr_decay_steps
    return cfg.lr_start + (cfg.lr_end - cfg.lr_start) * frac


def resolve_device(name: str) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise SmspaceError(f"--device cuda: no CUDA GPU is usable here (torch {torch.__version__})")
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise SmspaceError(f"unknown --device {name!r} (cpu or cuda)")
    return torch.device(name)


def run_dataset(cfg: TrainConfig, where: str) -> Dataset:
    """The dataset a run trains on, refused if it is not the one the run recorded (regenerated)."""
    ds = Dataset(cfg.dataset)
    recorded = (cfg.dataset_config_hash, cfg.dataset_shards_sha256)
    found = (ds.manifest.config_hash, ds.manifest.shards_digest)
    for name, was, now in zip(("config hash", "shard hashes"), recorded, found, strict=True):
        if was and was != now:  # empty: a config written by hand or by smspace 0.1
            raise SmspaceError(
                f"dataset {ds.url} is not the one {where} was trained on (its {name} changed); train a new run instead"
            )
    for size, shard in zip(ds.shard_sizes(), ds.manifest.shards, strict=True):
        if size != shard["bytes"]:
            raise SmspaceError(f"shard {ds.url}/{shard['file']} is not the size its manifest records")
    return ds


def open_member(run: RunDir, cfg: TrainConfig, device: torch.device, ranks: Ranks = SINGLE) -> Member:
    ds = run_dataset(cfg, str(run.path))
    if not cfg.encoder_layers:  # a config built by hand: resolved (the setup's encoder), and recorded so
        cfg = cfg.for_dataset(ds.store, ds.manifest)
        if ranks.primary:
            run.write_config(cfg)
    batch = per_rank_batch(cfg.batch_size, ranks)
    stream = TransitionStream(
        ds, batch, seed=cfg.seed, window=cfg.shuffle_window, rank=ranks.rank, world_size=ranks.world
    )
    return Member(run, cfg, ds, stream, EvalData.load(ds, cfg.eval_transitions, device))


def resume_members(learner: Learner, members: list[Member], device: torch.device, ranks: Ranks = SINGLE) -> int:
    """Load every run's checkpoint, all at one step, which is returned. Members of an ensemble
    that a kill left between the checkpoint writes of one evaluation (some at step S, the others
    at the evaluation before) are rolled back to the step all reached: the ensemble resumes as the
    uninterrupted one would have gone on."""
    from smspace.train.fit import check_checkpoint  # the lone model's shapes: what every checkpoint holds

    checkpoints = [m.run.load_checkpoint(str(device)) for m in members]
    step = min(int(ckpt["step"]) for ckpt in checkpoints)
    for r, (m, ckpt) in enumerate(zip(members, checkpoints, strict=True)):
        if int(ckpt["step"]) > step:
            try:
                ckpt = m.run.roll_back(str(device))
            except FileNotFoundError:
                ckpt = {"step": None}
            if ckpt["step"] != step:
                raise SmspaceError(
                    f"runs trained together must resume at one step: {m.run.path} is at step "
                    f"{checkpoints[r]['step']} and keeps no checkpoint of step {step}"
                )
        check_checkpoint(ckpt, m.cfg, m.dataset.manifest, f"{m.run.path}/checkpoint.pt")
        m.run.check_whole(ckpt)
        learner.load(r, ckpt)
        m.stream.load_state_dict(ckpt["stream"])
        m.elapsed = float(ckpt["elapsed_s"])
        m.rows = [row for row in m.run.metrics() if row["step"] <= step]
        if ranks.primary:  # the run folder is rank 0's
            m.run.truncate_after(step)
    return step


def train(
    learner: Learner,
    members: list[Member],
    step: int,
    progress: bool = True,
    ranks: Ranks = SINGLE,
    synced: Callable[[], bool] = lambda: True,
    on_step: Callable[[int], None] | None = None,
) -> None:
    """Train every member from `step` (0, or where `resume_members` left them) to cfg.steps. Under
        DDP every rank steps, rank 0 alone evaluates and writes, and at each evaluation all ranks check
        (`synced`) that they hold identical weights. `on_step`: told the step about every second (a
    sweep's progress across processes)."""
    cfg = members[0].cfg  # the schedule is shared: ensembles check that their runs agree on it
    count = len(members)
    device = members[0].data.m_regular.device

    def record(step: int, train_loss: np.ndarray, wall: float) -> None:
        if not synced():
            raise TrainingFailed(f"the {ranks.world} ranks hold different weights at step {step}; stopped")
        if not ranks.primary:
            return
        losses, hs, preds = learner.evaluate()
        lr = learning_rate(cfg, step)
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
            m.run.write_evaluation(m.rows, hs[r], m.data.p_regular, preds[r], true, state, keep_previous=count > 1)

    def diverged(at: int, losses: np.ndarray) -> TrainingFailed:
        bad = ", ".join(members[r].run.name for r in np.flatnonzero(~np.isfinite(losses)))
        last = members[0].rows[-1]["step"] if members[0].rows else 0
        return TrainingFailed(
            f"loss became NaN or inf at step {at} in {bad}; stopped, the checkpoint of step {last} is kept"
        )

    if step == 0 and not any(m.rows for m in members):  # resumed from a step-0 checkpoint: recorded already
        record(0, np.full(count, math.nan), 0.0)
    batches = [iter(DataLoader(m.stream, batch_size=None, num_workers=m.cfg.loader_workers)) for m in members]
    check_each_step = device.type == "cpu"  # .item() is free on a CPU, a sync on a GPU
    loss_sum = torch.zeros(count, dtype=torch.float32, device=device)
    loss_count = 0
    desc = "training" if count == 1 else f"ensemble of {count}"
    bar = Progress(desc, cfg.steps, "step", initial=step, enabled=progress and ranks.primary)
    last_tick = time.monotonic()
    compile_note: dict[str, str] = {}
    try:
        t0 = time.perf_counter()
        while step < cfg.steps:
            learner.set_lr(learning_rate(cfg, step))
            started = time.perf_counter()
            losses = mean_over_ranks(learner.train_step([_next_batch(b) for b in batches]), ranks)
            if cfg.compile and not compile_note:  # the first step of a session pays for compilation
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
        for m in members:
            m.run.set_status("finished", step, message)


def _summary(rows: list[dict[str, Any]]) -> dict[str, str]:
    """The last evaluation for a progress line: the run's values, or an ensemble's medians."""
    prefix = "" if len(rows) == 1 else "median "
    shown = {"loss": ("eval_loss", ".4g"), "D_topo": ("d_topo", ".3g"), "D_metric": ("d_metric", ".3g")}
    return {prefix + name: format(float(np.median([r[key] for r in rows])), fmt) for name, (key, fmt) in shown.items()}


def _next_batch(batches) -> tuple[torch.Tensor, ...]:
    try:
        return next(batches)
    except SmspaceError as e:
        # a DataLoader worker's error comes back with its traceback in the message: keep its own line
        lines = [ln for ln in str(e).splitlines() if ln.strip()]
        raise type(e)(lines[-1].split(": ", 1)[-1] if len(lines) > 1 else str(e)) from e


@contextmanager
def recorded_outcome(runs: list[RunDir]) -> Iterator[None]:
    """Whatever stops training early — bad data, a NaN, Ctrl-C, a bug — is written in each run's
    status, so that no run looks alive after its process is gone. Best effort, within a few
    seconds: the storage may be what failed, and the cause must not be hidden behind its error."""
    try:
        yield
    except SmspaceError as e:
        _mark(runs, "failed", str(e))
        raise
    except KeyboardInterrupt:
        _mark(runs, "interrupted", "interrupted; the checkpoint of step {step} is kept: resume it")
        raise
    except Exception as e:
        _mark(runs, "failed", f"{type(e).__name__}: {e}")
        raise


def _mark(runs: list[RunDir], state: str, message: str) -> None:
    """Each run's status, with the step of its last evaluation (hence of its checkpoint)."""

    def mark(run: RunDir) -> None:
        step = run.status()["step"]
        run.set_status(state, step, " ".join(message.replace("{step}", str(step)).split()))

    run_within([lambda run=run: mark(run) for run in runs])
