"""A run folder: config, metrics table, learned h per evaluation, checkpoint, status.

Every file is replaced atomically, so a run killed at any moment keeps its last good checkpoint
and a metrics table that resume trims back to that checkpoint.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import re  # only for its exception type: checkpoints load with weights_only=True
import shutil
import socket
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from common.errors import SmspaceError
from common.locks import HeldLock, hold_lock
from lake.atomic import remove_partials, write_atomic
from train.config import TrainConfig

CONFIG = "config.json"
METRICS = "metrics.parquet"
EMBEDDINGS = "embeddings"
CHECKPOINT = "checkpoint.pt"
STATUS = "status.json"
LOCK = ".lock"  # held (flock) by the process training the run

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


def _parquet_bytes(table: pa.Table) -> bytes:
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    return buf.getvalue()


def embedding_file(step: int) -> str:
    return f"step-{step:07d}.parquet"


def array_file(name: str, step: int) -> str:
    """An array saved beside the embeddings: s_t1_pred at every evaluation, s_t1_true at step 0."""
    return f"{name}-{step:07d}.npy"


PREDICTED, TRUE = "s_t1_pred", "s_t1_true"
EVALUATION_FILE = re.compile(r"[a-z0-9_]+-(?P<step>\d{7})\.(parquet|npy)")  # step-…, s_t1_pred-…, s_t1_true-…


class RunDir:
    def __init__(self, path: Path):
        self.path = Path(path)
        self._lock: HeldLock | None = None

    def claim(self) -> None:
        """Become the one process training this run; another one gets a clear refusal."""
        if self._lock is None:
            self._lock = hold_lock(self.path / LOCK, f"{self.path} is being trained by another process", wait=False)

    def release(self) -> None:
        """Stop being the trainer (to hand the run to another process, which claims it)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    # -- lifecycle ------------------------------------------------------------------------
    @classmethod
    def create(cls, path: Path, cfg: TrainConfig, overwrite: bool) -> RunDir:
        run = cls(path)
        if run.path.exists() and not run.path.is_dir():
            raise SmspaceError(f"output {run.path} is a file, not a folder")
        if (run.path / CONFIG).exists() and not overwrite:
            raise SmspaceError(f"{run.path} already holds a run: pass --resume to continue it or --overwrite")
        elif run.path.exists() and any(p.name != LOCK for p in run.path.iterdir()) and not overwrite:
            raise SmspaceError(f"{run.path} is not empty and holds no run; choose another --out")
        try:
            run.path.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SmspaceError(f"cannot create run folder {run.path}: {e.strerror or e}") from e
        run.claim()
        if (run.path / CONFIG).exists():
            run._clear()
        run.write_config(cfg)
        return run

    def write_config(self, cfg: TrainConfig) -> None:
        write_atomic(self.path / CONFIG, (json.dumps(cfg.to_dict(), indent=1) + "\n").encode())

    @classmethod
    def open(cls, path: Path) -> RunDir:
        run = cls(path)
        if not (run.path / CONFIG).exists():
            raise SmspaceError(f"{run.path} is not a run folder (no {CONFIG})")
        return run

    def _clear(self) -> None:
        for name in (CONFIG, METRICS, CHECKPOINT, STATUS):
            (self.path / name).unlink(missing_ok=True)
        shutil.rmtree(self.path / EMBEDDINGS, ignore_errors=True)
        remove_partials(self.path)

    @property
    def config(self) -> TrainConfig:
        try:
            return TrainConfig.from_dict(json.loads((self.path / CONFIG).read_text()))
        except (json.JSONDecodeError, UnicodeDecodeError, TypeError, AttributeError) as e:
            raise SmspaceError(f"{self.path / CONFIG} is unreadable ({type(e).__name__})") from e

    # -- status ---------------------------------------------------------------------------
    def set_status(self, state: str, step: int, message: str = "") -> None:
        """The run's state; a running one records who runs it, so that `ls` can tell when it died."""
        status = {"state": state, "step": step, "message": message}
        if state == "running":
            status |= {"pid": os.getpid(), "host": socket.gethostname()}
        write_atomic(self.path / STATUS, json.dumps(status).encode())

    def status(self) -> dict[str, Any]:
        """The recorded state; "running" becomes "stale" when its process is gone from this host."""
        try:
            status = json.loads((self.path / STATUS).read_text())
        except FileNotFoundError:
            return {"state": "created", "step": 0, "message": ""}
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise SmspaceError(f"{self.path / STATUS} is unreadable ({type(e).__name__})") from e
        mine = status.get("host") == socket.gethostname()
        if status.get("state") == "running" and mine and not _alive(status.get("pid")):
            status |= {"state": "stale", "message": "its process is gone; resume with --resume"}
        return status

    # -- metrics and embeddings -------------------------------------------------------------
    def metrics(self) -> list[dict[str, Any]]:
        path = self.path / METRICS
        if not path.exists():
            return []
        try:
            return _read_parquet(path).to_pylist()
        except (OSError, pa.ArrowException) as e:
            raise SmspaceError(f"{path} is unreadable ({type(e).__name__})") from e

    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        write_atomic(self.path / METRICS, _parquet_bytes(pa.Table.from_pylist(rows, schema=METRICS_SCHEMA)))

    def write_embeddings(self, step: int, h: np.ndarray, p: np.ndarray, extra: dict[str, np.ndarray]) -> None:
        """h of the regular sampling with its p (so anyone can recompute the metrics), plus extras."""
        folder = self.path / EMBEDDINGS
        folder.mkdir(exist_ok=True)
        columns = {
            "index": pa.array(np.arange(len(h), dtype=np.int32)),
            "h": _fixed_list(h),
            "p": _fixed_list(p),
        }
        table = pa.table(columns, metadata={"step": str(step)})
        write_atomic(folder / embedding_file(step), _parquet_bytes(table))
        for name, value in extra.items():
            write_atomic(folder / array_file(name, step), _npy_bytes(value))

    def embeddings(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        table = _read_parquet(self.path / EMBEDDINGS / embedding_file(step))
        return _from_fixed_list(table["h"]), _from_fixed_list(table["p"])

    def predictions(self, step: int) -> np.ndarray:
        """The normalised s_t1 the network predicted at `step` for the first evaluation transitions."""
        return np.load(self.path / EMBEDDINGS / array_file(PREDICTED, step), allow_pickle=False)

    def true_s_t1(self) -> np.ndarray:
        """The normalised s_t1 those predictions aim at (saved once, at step 0)."""
        return np.load(self.path / EMBEDDINGS / array_file(TRUE, 0), allow_pickle=False)

    def truncate_after(self, step: int) -> None:
        """Drop what evaluations after `step` wrote, and whatever killed writers left half-done."""
        remove_partials(self.path)
        folder = self.path / EMBEDDINGS
        if not folder.is_dir():
            return
        remove_partials(folder)
        for path in folder.iterdir():
            match = EVALUATION_FILE.fullmatch(path.name)
            if match and int(match["step"]) > step:
                path.unlink()

    # -- checkpoints --------------------------------------------------------------------------
    def save_checkpoint(self, state: dict[str, Any]) -> None:
        buf = io.BytesIO()
        torch.save(state, buf)
        write_atomic(self.path / CHECKPOINT, buf.getvalue())

    def checkpoint_step(self) -> int:
        """The step of the last checkpoint; 0 when there is none yet."""
        return int(self.load_checkpoint()["step"]) if (self.path / CHECKPOINT).exists() else 0

    def load_checkpoint(self, device: str = "cpu") -> dict[str, Any]:
        path = self.path / CHECKPOINT
        if not path.exists():
            raise SmspaceError(f"{self.path} has no checkpoint to resume from")
        try:
            return torch.load(path, map_location=device, weights_only=True)
        except pickle.UnpicklingError as e:  # weights_only refused an object: never load it another way
            raise SmspaceError(
                f"{path} is not a smspace checkpoint (it holds objects other than tensors and plain data); "
                "it was not loaded"
            ) from e
        except Exception as e:
            raise SmspaceError(f"checkpoint {path} is unreadable ({type(e).__name__}); it was not loaded") from e


def _read_parquet(path: Path) -> pa.Table:
    with open(path, "rb") as fh:  # pyarrow cannot open a path that is not valid UTF-8; Python can
        return pq.read_table(fh)


def _alive(pid: Any) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def _fixed_list(x: np.ndarray) -> pa.FixedSizeListArray:
    x = np.ascontiguousarray(x, np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


def _from_fixed_list(col: pa.ChunkedArray) -> np.ndarray:
    arr = col.combine_chunks()
    return arr.values.to_numpy().reshape(len(arr), arr.type.list_size)


def _npy_bytes(x: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(x), allow_pickle=False)
    return buf.getvalue()
