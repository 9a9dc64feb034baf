"""TensorBoard files of a run, so that `tensorboard --logdir runs/` follows every run of a study
while it trains (and W&B or MLflow import them: README, "Watching training").

Each evaluation is one event file, `events.out.tfevents.<step>.smspace`, holding its scalars:
names sort by step, which is the order TensorBoard reads a folder in, and a file is written once,
whole, through the run's store (a folder or object storage; nothing is appended). The learned h of
the latest evaluation is the projector's embedding, with p (and the step) as its metadata.
Written with tensorboardX (small: protobuf only); tensorboard itself is only needed to look.
"""

from __future__ import annotations

import io
import math
import struct
import time
from typing import Any

import numpy as np
from tensorboardX.proto.event_pb2 import Event
from tensorboardX.record_writer import masked_crc32c
from tensorboardX.summary import scalar

FOLDER = "tensorboard"
TENSORS, METADATA, PROJECTOR = "tensors.tsv", "metadata.tsv", "projector_config.pbtxt"
SCALARS = {  # tag: metrics column
    "loss/eval": "eval_loss",
    "loss/train": "train_loss",
    "space/D_topo": "d_topo",
    "space/D_metric": "d_metric",
    "lr": "lr",
}


def event_file(step: int) -> str:
    return f"events.out.tfevents.{step:012d}.smspace"


def _record(data: bytes) -> bytes:
    """One TFRecord: length, its masked CRC-32C, the data, its masked CRC-32C."""
    header = struct.pack("<Q", len(data))
    return header + struct.pack("<I", masked_crc32c(header)) + data + struct.pack("<I", masked_crc32c(data))


def evaluation_events(row: dict[str, Any], wall_time: float | None = None) -> bytes:
    """The event file of one evaluation (a metrics row): a version record, then one scalar per
    metric that has a finite value (the training loss of step 0 is not one)."""
    wall = time.time() if wall_time is None else wall_time
    events = [Event(wall_time=wall, step=row["step"], file_version="brain.Event:2")]
    for tag, column in SCALARS.items():
        value = row.get(column)
        if value is not None and math.isfinite(value):
            events.append(Event(wall_time=wall, step=row["step"], summary=scalar(tag, float(value))))
    return b"".join(_record(e.SerializeToString()) for e in events)


def projector_files(h: np.ndarray, p: np.ndarray, step: int) -> dict[str, bytes]:
    """The projector's embedding: h of the regular sampling, each point's p and the step as
    metadata (colour by p_x or p_y to see whether h laid out space)."""
    tensors = io.StringIO()
    np.savetxt(tensors, np.asarray(h, dtype=np.float64), delimiter="\t", fmt="%.7g")
    meta = io.StringIO()
    header = ["index", *[f"p_{axis}" for axis in "xyz"[: p.shape[1]]], "step"]
    meta.write("\t".join(header) + "\n")
    for i, row in enumerate(np.asarray(p, dtype=np.float64)):
        meta.write("\t".join([str(i), *(f"{v:.6g}" for v in row), str(step)]) + "\n")
    config = (
        "embeddings {\n"
        f'  tensor_name: "h (step {step})"\n'
        f'  tensor_path: "{TENSORS}"\n'
        f'  metadata_path: "{METADATA}"\n'
        "}\n"
    )
    return {TENSORS: tensors.getvalue().encode(), METADATA: meta.getvalue().encode(), PROJECTOR: config.encode()}
