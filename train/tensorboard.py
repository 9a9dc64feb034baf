"""TensorBoard's view of a run, so that `tensorboard --logdir runs/` follows every run of a study
while it trains, compares a grid in its HParams tab (and W&B or MLflow import them: README,
"Watching training").

A run is one event stream, `events.out.tfevents.smspace` in the run folder itself (so TensorBoard
names the run after its folder): the run's terms as an HParams session, then every evaluation's
scalars in step order. The whole stream is written again at each evaluation from the metrics
table, through the run's store (a folder or object storage; nothing is appended), so a resume that
trims evaluations trims the stream with them. The learned h of the latest evaluation is the
projector's embedding (its data in `tensorboard/`), with p (and the step) as its metadata.
Written with tensorboardX (small: protobuf only); tensorboard itself is only needed to look.
"""

from __future__ import annotations

import io
import json
import math
import struct
import time
from typing import Any

import numpy as np

EVENTS = "events.out.tfevents.smspace"  # the run's one stream; TensorBoard reads any name holding "tfevents"
FOLDER = "tensorboard"  # the projector's data
TENSORS, METADATA, PROJECTOR = "tensors.tsv", "metadata.tsv", "projector_config.pbtxt"
SCALARS = {  # tag: metrics column
    "loss/eval": "eval_loss",
    "loss/train": "train_loss",
    "space/D_topo": "d_topo",
    "space/D_metric": "d_metric",
    "lr": "lr",
}
HPARAMS = (  # the terms a grid varies, as the HParams tab's columns
    "setup", "mode", "seed", "n_h", "model", "model_params", "precision", "steps", "batch_size",
    "lr_start", "lr_end", "encoder_layers", "predictor_layers", "dataset_id",
)  # fmt: skip


def _record(data: bytes) -> bytes:
    """One TFRecord: length, its masked CRC-32C, the data, its masked CRC-32C."""
    from tensorboardX.record_writer import masked_crc32c  # here: listing run folders imports this module

    header = struct.pack("<Q", len(data))
    return header + struct.pack("<I", masked_crc32c(header)) + data + struct.pack("<I", masked_crc32c(data))


def hparam_values(terms: dict[str, Any]) -> dict[str, str | float | bool]:
    """The run's terms as HParams values: numbers stay numbers (the tab sorts and plots them),
    lists and objects become their JSON text (one value per distinct network)."""
    values: dict[str, str | float | bool] = {}
    for key in HPARAMS:
        value = terms.get(key)
        if isinstance(value, bool | str):
            values[key] = value
        elif isinstance(value, int | float):
            values[key] = float(value)
        elif value is not None:
            values[key] = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return values


def run_events(terms: dict[str, Any], rows: list[dict[str, Any]], now: float | None = None) -> bytes:
    """The run's event stream: a version record, its HParams session (its terms), then one scalar
    per metric with a finite value (step 0 has no training loss) for each evaluation, in step
    order. Wall times count back from `now` by the recorded elapsed training time."""
    from tensorboardX.proto.event_pb2 import Event  # here, as in _record: ~0.5 s of imports
    from tensorboardX.summary import hparams, scalar

    now = time.time() if now is None else now
    last = rows[-1]["elapsed_s"] if rows else 0.0
    start = now - last
    _, session_start, _ = hparams(hparam_values(terms), {})
    events = [
        Event(wall_time=start, step=0, file_version="brain.Event:2"),
        Event(wall_time=start, step=0, summary=session_start),
    ]
    for row in rows:
        wall = start + row["elapsed_s"]
        for tag, column in SCALARS.items():
            value = row.get(column)
            if value is not None and math.isfinite(value):
                events.append(Event(wall_time=wall, step=row["step"], summary=scalar(tag, float(value))))
    return b"".join(_record(e.SerializeToString()) for e in events)


def projector_files(h: np.ndarray, p: np.ndarray, step: int) -> dict[str, bytes]:
    """The projector's embedding: h of the regular sampling, each point's p and the step as
    metadata (colour by p_x or p_y to see whether h laid out space). The config lies beside the
    event stream (the projector looks for it in the run's folder), its data in FOLDER."""
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
        f'  tensor_path: "{FOLDER}/{TENSORS}"\n'
        f'  metadata_path: "{FOLDER}/{METADATA}"\n'
        "}\n"
    )
    return {f"{FOLDER}/{TENSORS}": tensors.getvalue().encode(), f"{FOLDER}/{METADATA}": meta.getvalue().encode(),
            PROJECTOR: config.encode()}  # fmt: skip
