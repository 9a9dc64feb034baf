"""A run folder: config, metrics table, learned h per evaluation, checkpoint, status.

Every file is replaced atomically, so a run killed at any moment keeps its last good checkpoint
and a metrics table that resume trims back to that checkpoint.
"""

from __future__ import annotations

import io
import os
import pickle
import re
import socket
import uuid
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, Self

import numpy as np
import pyarrow as pa

from smspace.common import provenance
from smspace.common.errors import SmspaceError
from smspace.lake import parquet
from smspace.lake.records import RUN_CONFIG, RUN_STATUS
from smspace.lake.store import (
    StorageUnreachable,
    Store,
    entries,
    exists,
    listing,
    open_store,
    remove_folder,
    remove_partials,
)
from smspace.train import tensorboard
from smspace.train.claim import LOCK, Claim
from smspace.train.config import TrainConfig
from smspace.train.status import RunStatus

CONFIG = RUN_CONFIG.file
METRICS = "metrics.parquet"
EMBEDDINGS = "embeddings"
SUBFOLDERS = (EMBEDDINGS, tensorboard.FOLDER)
CHECKPOINT = "checkpoint.pt"
PREVIOUS = "checkpoint-previous.pt"  # members of an ensemble: the evaluation before, to roll back to
STATUS = RUN_STATUS.file
RUN_ID = "run_id"  # in config.json, the checkpoint, the metrics' and embeddings' metadata, status.json

METRICS_SCHEMA = pa.schema(
    [
        ("step", pa.int64()),
        ("lr", pa.float64()),
        ("train_loss", pa.float64()),  # mean training loss since the previous evaluation
        ("eval_loss", pa.float64()),  # loss on the fixed evaluation transitions
        ("d_topo", pa.float64()),
        ("d_metric", pa.float64()),
        ("elapsed_s", pa.float64()),  # wall-clock training time so far (the only non-reproducible column)
    ]
)


def embedding_file(step: int) -> str:
    return f"step-{step:07d}.parquet"


def array_file(name: str, step: int) -> str:
    """An array saved beside the embeddings: s_t1_pred at every evaluation, s_t1_true at step 0."""
    return f"{name}-{step:07d}.npy"


PREDICTED, TRUE = "s_t1_pred", "s_t1_true"
EVALUATION_FILE = re.compile(r"[a-z0-9_]+-(?P<step>\d{7})\.(parquet|npy)")  # step-…, s_t1_pred-…, s_t1_true-…


class RunView:
    """A run folder read, never written: what `ls`, `info`, `report`, `view` and smspace.open_run
    need. Only a RunDir (below) writes, and only the process that claimed it."""

    def __init__(self, where: Path | str | Store):
        self.store: Store = open_store(where)
        self._run_id: str | None = None

    @property
    def url(self) -> str:
        """Where the folder is: a local path or an fsspec URL, for messages and listings (a local
        run's Path is `local_path`)."""
        return self.store.url

    @property
    def name(self) -> str:
        return self.store.name

    @property
    def local_path(self) -> Path | None:
        return self.store.local_path

    def _embeddings(self) -> Store:
        return self.store.child(EMBEDDINGS)

    @classmethod
    def open(cls, where: Path | str | Store) -> Self:
        run = cls(where)
        try:
            found = exists(run.store, CONFIG)
        except NotADirectoryError:
            found = False
        if not found:
            raise SmspaceError(f"{run.url} is not a run folder (no {CONFIG})")
        return run

    @property
    def run_id(self) -> str:
        """The id config.json gives this run; every file of the run carries it, so a folder whose
        parts were written by different runs is told apart ("" for runs of an older smspace)."""
        if self._run_id is None:
            self._run_id = self.config.run_id
        return self._run_id

    def _read(self, name: str, store: Store | None = None) -> bytes:
        return (store or self.store).read(name)

    @property
    def config(self) -> TrainConfig:
        try:
            raw = RUN_CONFIG.decode(self._read(CONFIG), f"{self.url}/{CONFIG}")
        except FileNotFoundError:
            raise SmspaceError(f"{self.url} is not a run folder (no {CONFIG})") from None
        try:
            return TrainConfig.from_dict(raw)
        except (TypeError, AttributeError) as e:
            raise SmspaceError(f"{self.url}/{CONFIG} is unreadable ({type(e).__name__})") from e
        except SmspaceError as e:  # a value no flag would take (a NaN lr_start): name the file
            raise SmspaceError(f"{self.url}/{CONFIG} holds a config no run could have: {e}") from e

    def recorded_keys(self) -> set[str]:
        """The config fields config.json holds (an older smspace recorded fewer)."""
        try:
            return set(RUN_CONFIG.decode(self._read(CONFIG), f"{self.url}/{CONFIG}"))
        except (FileNotFoundError, SmspaceError):
            return set()

    def status(self) -> RunStatus:
        """The recorded state (train/status.py); "running" becomes "stale" when its process is gone
        from this host."""
        try:
            data = self._read(STATUS)
        except FileNotFoundError:
            return RunStatus.created()
        return RunStatus.decode(data, f"{self.url}/{STATUS}").as_seen_here()

    def metrics(self) -> list[dict[str, Any]]:
        try:
            table = parquet.read_table(self._read(METRICS))
        except FileNotFoundError:
            return []
        except (OSError, pa.ArrowException) as e:
            raise SmspaceError(f"{self.url}/{METRICS} is unreadable ({type(e).__name__})") from e
        missing = [f.name for f in METRICS_SCHEMA if f.name not in table.schema.names]
        if missing:  # written by hand or by another tool: every reader would fail on a KeyError
            raise SmspaceError(f"{self.url}/{METRICS} is unreadable (no column {', '.join(missing)})")
        return table.to_pylist()

    def summary(self) -> dict[str, Any]:
        """One line of `smtrain ls`, the head of `smtrain info`: its state and its last evaluation."""
        cfg, rows, status = self.config, self.metrics(), self.status()
        last = rows[-1] if rows else {}
        return {
            "run": self.url,
            "dataset_id": cfg.dataset_id,
            "state": status.state,
            "message": status.message,
            "step": last.get("step", 0),
            "steps": cfg.steps,
            "n_h": cfg.n_h,
            "seed": cfg.seed,
            "model": cfg.model,
            "model_params": cfg.model_params,
            "precision": cfg.precision,
            "eval_loss": last.get("eval_loss"),
            "d_topo": last.get("d_topo"),
            "d_metric": last.get("d_metric"),
            "elapsed_s": last.get("elapsed_s"),
        }

    def embeddings(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        table = parquet.read_table(self._read(embedding_file(step), self._embeddings()))
        return parquet.from_fixed_list(table["h"]), parquet.from_fixed_list(table["p"])

    def predictions(self, step: int) -> np.ndarray:
        """The normalised s_t1 the network predicted at `step` for the first evaluation transitions."""
        return _npy(self._read(array_file(PREDICTED, step), self._embeddings()))

    def true_s_t1(self) -> np.ndarray:
        """The normalised s_t1 those predictions aim at (saved once, at step 0)."""
        return _npy(self._read(array_file(TRUE, 0), self._embeddings()))

    def check_whole(self, checkpoint: dict[str, Any]) -> None:
        """Refuse a folder whose config, metrics and checkpoint were written by different runs
        (two processes writing one folder): continuing it would mix them."""
        ids = {CONFIG: self.run_id, CHECKPOINT: str(checkpoint.get(RUN_ID) or "")}
        try:
            metadata = parquet.read_schema(self._read(METRICS)).metadata or {}
            ids[METRICS] = metadata.get(RUN_ID.encode(), b"").decode()
        except FileNotFoundError:
            pass
        found = {name: run_id for name, run_id in ids.items() if run_id}  # "": written by an older smspace
        if len(set(found.values())) > 1:
            parts = ", ".join(f"{name} of run {run_id[:8]}" for name, run_id in found.items())
            raise SmspaceError(
                f"{self.url} holds parts of different runs ({parts}): two processes wrote it; "
                "train it anew with --overwrite"
            )

    def has_checkpoint(self) -> bool:
        return exists(self.store, CHECKPOINT)

    def checkpoint_step(self) -> int:
        """The step of the last checkpoint; 0 when there is none yet."""
        return int(self.load_checkpoint()["step"]) if self.has_checkpoint() else 0

    def load_checkpoint(self, device: str = "cpu") -> dict[str, Any]:
        return loaded_checkpoint(self.checkpoint_bytes(), f"{self.url}/{CHECKPOINT}", device)

    def checkpoint_bytes(self) -> bytes:
        try:
            data = self._read(CHECKPOINT)
        except FileNotFoundError:
            raise SmspaceError(
                f"{self.url} has no checkpoint to resume from (stopped before its first): "
                "run the command that created it with --overwrite"
            ) from None
        return data


def loaded_checkpoint(data: bytes, where: str, device: str) -> dict[str, Any]:
    import torch  # here, not at the top: reading a run folder (ls, info, report) needs no torch

    try:
        return torch.load(io.BytesIO(data), map_location=device, weights_only=True)
    except pickle.UnpicklingError as e:  # weights_only refused an object: never load it another way
        raise SmspaceError(
            f"{where} is not a smspace checkpoint (it holds objects other than tensors and plain data); "
            "it was not loaded"
        ) from e
    except Exception as e:
        raise SmspaceError(f"checkpoint {where} is unreadable ({type(e).__name__}); it was not loaded") from e


class RunDir:
    """A run folder on this machine or on object storage (any fsspec URL), as the process training
    it writes it: every file is written whole in one step, the checkpoint last at each evaluation
    (it is the commit record: resume trims what later evaluations wrote).

    It holds the folder's RunView (`view`: everything read, config, metrics, status, checkpoints)
    and only what writing needs besides: the claim with the versions its writes are conditional on,
    the checkpoint it last wrote, the config it trains by."""

    def __init__(self, where: Path | str | Store):
        self.view = RunView(where)
        self.store = self.view.store
        self._claim = Claim(self.store, SUBFOLDERS)  # who writes, and over which versions: train/claim.py
        self._last_checkpoint: bytes | None = None  # the bytes this process last wrote or resumed from
        self._terms: dict[str, Any] | None = None  # the config this process trains by, once read or written

    @classmethod
    def open(cls, where: Path | str | Store) -> RunDir:
        """The run in `where`, refused in one line if it holds none."""
        return cls(RunView.open(where).store)

    @property
    def url(self) -> str:
        return self.view.url

    @property
    def name(self) -> str:
        return self.view.name

    @property
    def run_id(self) -> str:
        return self.view.run_id

    def claim(self) -> None:
        """Become the one process training this run; another one gets a clear refusal."""
        self._claim.claim()

    def release(self) -> None:
        """Stop being the trainer (to hand the run to another process, which claims it)."""
        self._claim.release()

    def _write(self, name: str, data: bytes, sub: str | None = None) -> None:
        """Every file of the run is written here, whole (train/claim.py: over its own versions only)."""
        self._claim.write(name, data, sub)

    def _delete(self, name: str, sub: str | None = None) -> None:
        self._claim.delete(name, sub)

    # -- lifecycle ------------------------------------------------------------------------
    @classmethod
    def create(cls, where: Path | str | Store, cfg: TrainConfig, overwrite: bool) -> RunDir:
        run = cls.creatable(where, overwrite)
        run.store.make()
        run.claim()
        if exists(run.store, CONFIG):
            run._clear()
        cfg = replace(cfg, run_id=uuid.uuid4().hex)  # an id, not a draw: nothing computed depends on it
        try:
            run._write(CONFIG, _config_bytes(cfg))  # create-only: of two processes creating it, one wins
        except StorageUnreachable:
            run.release()
            raise
        except SmspaceError:
            run.release()
            raise SmspaceError(
                f"{run.url}: another process created a run there meanwhile; choose another --out"
            ) from None
        run.view._run_id = cfg.run_id
        return run

    @classmethod
    def creatable(cls, where: Path | str | Store, overwrite: bool) -> RunDir:
        """The folder a new run may be created in (checked, nothing written)."""
        run = cls(where)
        if run.store.is_file():
            raise SmspaceError(f"output {run.url} is a file, not a folder")
        if exists(run.store, CONFIG) and not overwrite:
            if not exists(run.store, CHECKPOINT):
                raise SmspaceError(
                    f"{run.url} holds a run stopped before its first checkpoint: pass --overwrite to start it again"
                )
            raise SmspaceError(f"{run.url} already holds a run: pass --resume to continue it or --overwrite")
        if not overwrite and any(name != LOCK for name in entries(run.store)):
            raise SmspaceError(f"{run.url} is not empty and holds no run; choose another --out")
        return run

    def write_config(self, cfg: TrainConfig) -> None:
        self._write(CONFIG, _config_bytes(cfg))
        self._terms = asdict(cfg)

    def _trained_terms(self) -> dict[str, Any]:
        """The config this process trains by, read once: read again at every evaluation, a folder
        another process just cleared would be "not a run folder" instead of a lost write."""
        if self._terms is None:
            self._terms = asdict(self.view.config)
        return self._terms

    def record_session(self, device: str, threads: int, compile: str | None = None) -> None:
        """Add what this training session runs on to config.json (by the process that claimed it),
        with what it does of --compile (train/precision.py: the decision the steps act on)."""
        cfg = self.view.config
        done = {"compile": compile} if compile is not None else {}
        self.write_config(replace(cfg, sessions=[*cfg.sessions, provenance.session(device, threads, **done)]))

    def _clear(self) -> None:
        for name in (CONFIG, METRICS, CHECKPOINT, PREVIOUS, STATUS, tensorboard.EVENTS, tensorboard.PROJECTOR):
            self._delete(name)
        for sub in SUBFOLDERS:
            folder = self.store.child(sub)
            for name in listing(folder, "*"):
                self._delete(name, sub=sub)
            remove_folder(folder)
        remove_partials(self.store)

    # -- status ---------------------------------------------------------------------------
    def set_status(self, state: str, step: int, message: str = "") -> None:
        """The run's state; a running one records who runs it, so that `ls` can tell when it died."""
        if self._claim.lost:  # the folder is another process's now
            return
        status = RunStatus(state, step, message, self.run_id)
        if state == "running":
            status = replace(status, pid=os.getpid(), host=socket.gethostname())
        self._write(STATUS, status.encode())

    # -- metrics and embeddings -------------------------------------------------------------
    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        table = pa.Table.from_pylist(rows, schema=METRICS_SCHEMA).replace_schema_metadata({RUN_ID: self.run_id})
        self._write(METRICS, parquet.table_bytes(table))

    def write_embeddings(self, step: int, h: np.ndarray, p: np.ndarray, extra: dict[str, np.ndarray]) -> None:
        """h of the regular sampling with its p (so anyone can recompute the metrics), plus extras."""
        folder = self.store.child(EMBEDDINGS)
        folder.make()
        columns = {
            "index": pa.array(np.arange(len(h), dtype=np.int32)),
            "h": parquet.fixed_list(h),
            "p": parquet.fixed_list(p),
        }
        table = pa.table(columns, metadata={"step": str(step), RUN_ID: self.run_id})
        self._write(embedding_file(step), parquet.table_bytes(table), sub=EMBEDDINGS)
        for name, value in extra.items():
            self._write(array_file(name, step), _npy_bytes(value), sub=EMBEDDINGS)

    def write_tensorboard(self, rows: list[dict[str, Any]], h: np.ndarray, p: np.ndarray) -> None:
        """TensorBoard's view of the run so far (train/tensorboard.py): its terms and every
        evaluation's scalars as one stream, and h of the last as the projector's embedding."""
        self.store.child(tensorboard.FOLDER).make()
        self._write(tensorboard.EVENTS, tensorboard.run_events(self._trained_terms(), rows))
        for path, data in tensorboard.projector_files(h, p, rows[-1]["step"]).items():
            sub, _, name = path.rpartition("/")
            self._write(name, data, sub=sub or None)

    def write_evaluation(
        self,
        rows: list[dict[str, Any]],
        h: np.ndarray,
        p: np.ndarray,
        pred: np.ndarray,
        true: np.ndarray | None,
        checkpoint: dict[str, Any],
        keep_previous: bool = False,
    ) -> None:
        """An evaluation's files: h with p and the predictions, the metrics (`rows`, its row last),
        then the checkpoint, in this order, so that a kill between two writes leaves the checkpoint
        at or behind the metrics (resume trims them back to it); then the status."""
        step = rows[-1]["step"]
        extra = {PREDICTED: pred} | ({TRUE: true} if true is not None else {})
        self.write_embeddings(step, h, p, extra)
        self.write_tensorboard(rows, h, p)
        self.write_metrics(rows)
        self.save_checkpoint(checkpoint, keep_previous)
        self.set_status("running", step)

    def truncate_after(self, step: int) -> None:
        """Drop what evaluations after `step` wrote, and whatever killed writers left half-done."""
        remove_partials(self.store)
        folder = self.store.child(EMBEDDINGS)
        remove_partials(folder)
        for name in listing(folder, "*"):
            match = EVALUATION_FILE.fullmatch(name)
            if match and int(match["step"]) > step:
                self._delete(name, sub=EMBEDDINGS)
        remove_partials(self.store.child(tensorboard.FOLDER))
        if exists(self.store, tensorboard.EVENTS):  # the stream again, without the evaluations dropped
            rows = [row for row in self.view.metrics() if row["step"] <= step]
            self._write(tensorboard.EVENTS, tensorboard.run_events(self._trained_terms(), rows))

    # -- checkpoints --------------------------------------------------------------------------
    def load_checkpoint(self, device: str = "cpu") -> dict[str, Any]:
        """The checkpoint, as the view loads it; the writer keeps its bytes, which keep_previous
        keeps when the next checkpoint replaces it."""
        data = self.view.checkpoint_bytes()
        self._last_checkpoint = data
        return loaded_checkpoint(data, f"{self.url}/{CHECKPOINT}", device)

    def save_checkpoint(self, state: dict[str, Any], keep_previous: bool = False) -> None:
        """The new commit record; `keep_previous`: the one it replaces is kept beside it first, so
        that a member of an ensemble that a kill left one evaluation ahead of the others can be
        rolled back to the step all of them reached (train/fit.py, resume_from_folders)."""
        import torch

        buf = io.BytesIO()
        torch.save(state | {RUN_ID: self.run_id}, buf)
        if keep_previous and self._last_checkpoint is not None:
            self._write(PREVIOUS, self._last_checkpoint)
        self._write(CHECKPOINT, buf.getvalue())
        self._last_checkpoint = buf.getvalue()

    def roll_back(self, device: str = "cpu") -> dict[str, Any]:
        """The kept previous checkpoint, made the commit record again (this run was one evaluation
        ahead of its ensemble)."""
        data = self.store.read(PREVIOUS)
        self._write(CHECKPOINT, data)
        self._last_checkpoint = data
        return loaded_checkpoint(data, f"{self.url}/{PREVIOUS}", device)


def _config_bytes(cfg: TrainConfig) -> bytes:
    return RUN_CONFIG.encode(cfg.to_dict())


def _npy(data: bytes) -> np.ndarray:
    return np.load(io.BytesIO(data), allow_pickle=False)


def _npy_bytes(x: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(x), allow_pickle=False)
    return buf.getvalue()


def after_a_stop(where: str, world: int = 1) -> str:
    """What a run stopped part-way keeps, and the command that goes on from there. Stopped before
    its first checkpoint, --resume has nothing to start from and the original command refuses the
    folder (it holds a run's config): only --overwrite works, so that is what is said. The storage
    is asked within a few seconds: it may be what failed."""
    from smspace.common.bounded import run_within

    found: list[tuple[bool, int]] = []

    def look() -> None:
        run = RunView.open(where)
        found.append((exists(run.store, CHECKPOINT), run.status().step))

    run_within([look])
    nproc = f" --nproc {world}" if world > 1 else ""
    if found and not found[0][0]:
        return "it stopped before its first checkpoint, so nothing is kept: run the same command with --overwrite"
    kept = f"its checkpoint of step {found[0][1]} is kept" if found else "its last checkpoint is kept"
    return f"{kept}: smtrain fit --resume {where}{nproc}"
