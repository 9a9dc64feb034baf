"""Runs in run folders, trained by the engine: `smtrain fit` (one run) and a sweep's ensembles.

Each is: plan (every check before anything is written), open the run folder (claim it, record
the session), then call the engine (train/engine.py) with the run's data and the folder as its
sink. The engine evaluates at step 0 and every `eval_every` steps and the folder checkpoints right
after, so `--resume` continues from the last evaluation and ends bit-identical to an uninterrupted
run on the CPU.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
import torch

from smspace.common.bounded import run_within
from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.lake.store import within
from smspace.train import engine
from smspace.train.config import RUNS, TrainConfig, check_resources, flag_fields, flag_name
from smspace.train.contract import check_model
from smspace.train.distributed import SINGLE, Ranks, peer_errors, per_rank_batch
from smspace.train.engine import EvalData, Evaluation, Member, resolve_device
from smspace.train.loader import TransitionStream, walk_length
from smspace.train.precision import compile_decision, compiles
from smspace.train.run_dir import CHECKPOINT, RunDir
from smspace.train.terms import check_one_ensemble, resumed
from smspace.train.write_behind import WriteBehind

# --- plan -----------------------------------------------------------------------------------------


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
    given: frozenset[str],
    world: int,
) -> FitPlan:
    """Every check of `smtrain fit` before anything is written: the same on every rank, and in the
    launcher of --nproc before any rank starts. `given`: the config fields the caller set."""
    if resume is not None:
        extra = [flag_name(f) for f in flag_fields() if f.name in given and f.name != "steps"]
        if dataset or extra or overwrite:
            raise SmspaceError(f"--resume continues a run with its own config; drop {' '.join(extra) or 'DATASET'}")
        run = RunDir.open(resume)
        steps = template.steps if "steps" in given else None
        cfg, change = resumed(run.view.config, run.url, steps, world)
        ds = run_dataset(cfg, run.url).verify()
        manifest = ds.manifest
        cfg = cfg if cfg.encoder_layers else cfg.for_dataset(ds.store, manifest)  # a config built by hand
        check_resources(cfg, manifest)
        check_network(cfg, manifest)
        checkpoint = run.load_checkpoint()
        engine.check_checkpoint(checkpoint, cfg, *_shape(manifest), f"{run.url}/{CHECKPOINT}")
        run.view.check_whole(checkpoint)
        return FitPlan(cfg, run.url, resume=True, change=change)
    if dataset is None:
        raise SmspaceError("DATASET is required (or --resume RUN_DIR)")
    ds = Dataset.open(dataset, lake).verify()
    cfg = replace(template.for_dataset(ds.store, ds.manifest), world_size=world)
    resolve_device(cfg.device)
    check_resources(cfg, ds.manifest)
    check_window(cfg, ds.manifest)
    check_network(cfg, ds.manifest)
    per_rank_batch(cfg.batch_size, Ranks(0, world))
    where = out or f"{RUNS}/{cfg.run_name}"
    if within(where, ds.store):  # a run folder inside its dataset's folder would be taken for its files
        raise SmspaceError(f"--out {where} lies inside the dataset it trains on ({ds.store.url}); choose another")
    RunDir.creatable(where, overwrite)
    return FitPlan(cfg, str(where), resume=False, overwrite=overwrite)


def _shape(manifest) -> tuple[int, int]:
    """(n_motor, n_sensor): what a run's network is built for."""
    return manifest.n_motor, int(np.prod(manifest.sensor_shape))


def check_window(cfg: TrainConfig, manifest) -> None:
    """Windows of `--window` steps fit the dataset: a walk whose episodes hold them (the loader's
    own rule, train/loader.py), refused in one line before a run folder is written."""
    try:
        walk_length(manifest, cfg.window)
    except ValueError as e:
        raise SmspaceError(f"--window {cfg.window}: {e}") from None


def check_network(cfg: TrainConfig, manifest) -> None:
    """The run's model holds to its contract on a probe batch (train/contract.py), after the memory
    it needs was found to be there."""
    check_model(cfg, *_shape(manifest))


# --- the run's data -------------------------------------------------------------------------------


def run_dataset(cfg: TrainConfig, where: str) -> Dataset:
    """The dataset a run trains on, refused if it is not the one the run recorded (regenerated)."""
    ds = Dataset(cfg.dataset)
    recorded = (cfg.dataset_config_hash, cfg.dataset_shards_sha256)
    found = (ds.manifest.config_hash, ds.manifest.shards_digest)
    for name, was, now in zip(("config hash", "shard hashes"), recorded, found, strict=True):
        if was and was != now:  # empty: a config written by hand or before it recorded them
            raise SmspaceError(
                f"dataset {ds.url} is not the one {where} was trained on (its {name} changed); train a new run instead"
            )
    for size, shard in zip(ds.shard_sizes(), ds.manifest.shards, strict=True):
        if size != shard["bytes"]:
            raise SmspaceError(f"shard {ds.url}/{shard['file']} is not the size its manifest records")
    return ds


def eval_data(ds: Dataset, n: int, device: torch.device) -> EvalData:
    """The regular sampling and the first `n` transitions, normalised with the dataset's statistics."""
    m_norm, s_norm = normalisers(ds.manifest)
    m_reg, p_reg = ds.regular_sampling()
    head = ds.read_all(n)

    def col(name: str, norm) -> torch.Tensor:
        return torch.from_numpy(norm(getattr(head, name))).to(device)

    return EvalData(
        torch.from_numpy(m_norm(m_reg)).to(device),
        p_reg.astype(np.float64),
        col("m_t", m_norm),
        col("s_t", s_norm),
        col("m_t1", m_norm),
        col("s_t1", s_norm),
    )


def open_member(run: RunDir, cfg: TrainConfig, device: torch.device, ranks: Ranks = SINGLE) -> tuple[Member, Dataset]:
    """What the engine trains of a run folder: its config, stream and evaluation set."""
    ds = run_dataset(cfg, run.url)
    if not cfg.encoder_layers:  # a config built by hand: resolved (the setup's encoder), and recorded so
        cfg = cfg.for_dataset(ds.store, ds.manifest)
        if ranks.primary:
            run.write_config(cfg)
    batch = per_rank_batch(cfg.batch_size, ranks)
    ranked = {"rank": ranks.rank, "world_size": ranks.world}
    stream = TransitionStream(ds, batch, seed=cfg.seed, window=cfg.shuffle_window, steps=cfg.window, **ranked)
    return Member(run.url, cfg, stream, eval_data(ds, cfg.eval_transitions, device)), ds


# --- the run folder: where evaluations go, and where a resume starts ------------------------------


class RunFolders:
    """The engine's sink for run folders: each evaluation's files, then its checkpoint (the commit
    record); at the end, the status. Runs trained together keep their previous checkpoint too.
    `behind`: the files are written by a thread while the next steps train (train/write_behind.py);
    use it as a context manager then, so that every write is done before the runs' outcome is."""

    def __init__(self, runs: list[RunDir], behind: bool = False):
        self.runs = runs
        self._writer = WriteBehind() if behind else None

    def on_evaluation(self, ev: Evaluation) -> None:
        keep = len(self.runs) > 1
        run = self.runs[ev.r]
        rows = list(ev.rows)  # the trainer appends the next evaluation's row to its own list
        write = partial(run.write_evaluation, rows, ev.h, ev.p, ev.predictions, ev.true, ev.state, keep_previous=keep)
        if self._writer is None:
            write()
            return
        if ev.r == 0:  # one evaluation in flight at most: the previous one is written first
            self._writer.drain()
        self._writer.submit(write)

    def on_finish(self, step: int, message: str) -> None:
        if self._writer is not None:
            self._writer.drain()
        for run in self.runs:
            run.set_status("finished", step, message)

    def __enter__(self) -> RunFolders:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        if self._writer is None:
            return
        try:
            self._writer.close()
        except BaseException:
            if kind is None:
                raise
            # training failed already: its error is the one to report, the writes' is a consequence


def resume_from_folders(
    learner: engine.Learner,
    members: list[Member],
    runs: list[RunDir],
    device: torch.device,
    shape: tuple[int, int],
    ranks: Ranks = SINGLE,
) -> int:
    """Load every run's checkpoint, all at one step, which is returned. Members of an ensemble
    that a kill left between the checkpoint writes of one evaluation (some at step S, the others
    at the evaluation before) are rolled back to the step all reached: the ensemble resumes as the
    uninterrupted one would have gone on."""
    checkpoints = [run.load_checkpoint(str(device)) for run in runs]
    step = min(int(ckpt["step"]) for ckpt in checkpoints)
    for r, (run, ckpt) in enumerate(zip(runs, checkpoints, strict=True)):
        if int(ckpt["step"]) > step:
            try:
                checkpoints[r] = run.roll_back(str(device))
            except FileNotFoundError:
                checkpoints[r] = {"step": None}
            if checkpoints[r]["step"] != step:
                raise SmspaceError(
                    f"runs trained together must resume at one step: {run.url} is at step "
                    f"{ckpt['step']} and keeps no checkpoint of step {step}"
                )
        run.view.check_whole(checkpoints[r])
    step = engine.resume(learner, members, checkpoints, shape)
    for m, run in zip(members, runs, strict=True):
        m.rows = [row for row in run.view.metrics() if row["step"] <= step]
        if ranks.primary:  # the run folder is rank 0's
            run.truncate_after(step)
    return step


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
    """Each run's status, with the step of its checkpoint, read from it: a stop that fell between
    an evaluation's checkpoint and its status (written after) left the status one evaluation behind."""

    def mark(run: RunDir) -> None:
        try:
            step = run.view.checkpoint_step()
        except SmspaceError:  # unreadable: the status says what it last knew
            step = run.view.status().step
        run.set_status(state, step, " ".join(message.replace("{step}", str(step)).split()))

    run_within([lambda run=run: mark(run) for run in runs])


@contextmanager
def claimed(
    runs: list[RunDir], cfg: TrainConfig, threads: int, resume: bool, primary: bool = True
) -> Iterator[str | None]:
    """The runs held by this process while it trains them (a run another process trains is left
    untouched), each with this session recorded; the claims end with the training, however it ends.
    Yields what --compile does in this session (train/precision.py), decided on the run-steps left."""
    try:
        if primary:
            for run in runs:
                run.claim()
        done = min(_steps_done(run) for run in runs) if resume else 0
        decision = compile_decision(cfg.compile, len(runs) * max(0, cfg.steps - done))
        if primary:
            for run in runs:
                run.record_session(cfg.device, threads, decision)
        yield decision
    finally:
        for run in runs:
            run.release()


def _steps_done(run: RunDir) -> int:
    """The step of a run's last evaluation, as its status says (0 where it cannot say)."""
    try:
        return int(run.view.status().step)
    except SmspaceError:
        return 0


# --- one run --------------------------------------------------------------------------------------


def fit(
    cfg: TrainConfig, run: RunDir, resume: bool = False, ranks: Ranks = SINGLE, sinks: Sequence[engine.Sink] = ()
) -> dict[str, Any] | None:
    """Train (or resume) one run; returns its last metrics row (on rank 0; None on the others).
    `sinks`: more places each evaluation goes (a logger of one's own), after the run folder has
    committed it."""
    torch.set_num_threads(cfg.threads)  # 2 cores: oversubscribed threads made steps 10-40x slower
    device = resolve_device(cfg.device)
    claim = claimed([run], cfg, cfg.threads, resume, ranks.primary)
    with claim as decision, recorded_outcome([run] if ranks.primary else []):
        member, ds = open_member(run, cfg, device, ranks)
        cfg, shape = member.cfg, _shape(ds.manifest)
        model, optimizer = engine.build(cfg, *shape, device)
        learner = engine.SingleLearner(
            model, optimizer, member.data, ranks, cfg.precision, compiles(decision), seed=cfg.seed
        )
        step = resume_from_folders(learner, [member], [run], device, shape, ranks) if resume else 0
        with peer_errors(ranks):
            engine.train(learner, [member], step, [RunFolders([run]), *sinks], ranks=ranks)
    return member.rows[-1] if ranks.primary else None


# --- runs trained together (a sweep's ensemble) ---------------------------------------------------


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
    device = resolve_device(runs[0].view.config.device)
    with claimed(runs, runs[0].view.config, threads, resume) as decision, recorded_outcome(runs):
        opened = [open_member(run, run.view.config, device) for run in runs]
        members, manifests = [m for m, _ in opened], [ds.manifest for _, ds in opened]
        cfgs, shape = [m.cfg for m in members], _shape(manifests[0])
        check_one_ensemble(cfgs)
        if any(_shape(mf) != shape for mf in manifests):
            raise SmspaceError("runs of one ensemble must have datasets of the same setup")
        check_resources(cfgs[0], manifests[0], runs=len(runs))
        learner = engine.EnsembleLearner(cfgs, *shape, [m.data for m in members], device, compiles(decision))
        step = resume_from_folders(learner, members, runs, device, shape) if resume else 0
        with RunFolders(runs, behind=True) as folders:
            engine.train(learner, members, step, [folders], progress, on_step=on_step)
