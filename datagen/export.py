"""`smgen export`: a dataset in the formats other tools open natively.

- foxglove: one message per transition and topic, with Foxglove well-known protobuf schemas
  (`foxglove.RawImage` frames, `foxglove.PoseInFrame` positions) that Foxglove and rerun draw,
  plus a JSON `/transition` channel with every numeric field. log_time = a fixed epoch base +
  1 ms per transition index, so the file is deterministic and rerun shows real times.
- parquet: one row per transition for analysis tools; images as fixed_size_binary, the manifest
  in the schema metadata.
- hf: a Hugging Face `datasets` folder with a dataset card (datagen/export_hf.py).
- minari: a Minari datasets root holding the dataset as episodes (datagen/export_minari.py).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from smspace.common.atomic import atomic_writer
from smspace.common.cli import check_output
from smspace.common.errors import SmspaceError
from smspace.lake import parquet
from smspace.lake.dataset import Dataset
from smspace.lake.shards import Block
from smspace.lake.transitions import COLUMNS, Transitions

EPOCH_NS = 1_575_763_200 * 10**9  # 2019-12-08T00:00:00Z, NeurIPS 2019
STEP_NS = 10**6
FORMATS = ("foxglove", "parquet", "hf", "minari")


def _blocks(ds: Dataset, limit: int | None) -> Iterator[Block]:
    """The dataset's blocks in order, the last one cut at `limit` transitions."""
    done = 0
    for block in ds.blocks():
        if limit is not None and done + len(block.transitions) > limit:
            block = block.head(limit - done)
        if len(block.transitions):
            yield block
        done += len(block.transitions)
        if limit is not None and done >= limit:
            return


def export(ds: Dataset, fmt: str, out: Path, limit: int | None = None, overwrite: bool = False) -> int:
    """Write the export under a temporary name, renamed only when complete (never onto an input)."""
    if fmt not in FORMATS:
        raise SmspaceError(f"unknown export format {fmt!r} (choose from {', '.join(FORMATS)})")
    if fmt == "hf":  # a folder, not a file
        from smspace.datagen.export_hf import export_hf

        return export_hf(ds, out, limit, overwrite)
    if fmt == "minari":  # a Minari datasets root
        from smspace.datagen.export_minari import export_minari

        return export_minari(ds, out, limit, overwrite)
    check_output(out, overwrite, [ds.local_folder])
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SmspaceError(f"cannot write {out}: {e.strerror or e}") from e
    return (_foxglove if fmt == "foxglove" else _parquet)(ds, out, limit)


# -- foxglove ------------------------------------------------------------------------------------
TRANSITION_JSON_SCHEMA = {
    "type": "object",
    "title": "smspace.Transition",
    "properties": {
        "index": {"type": "integer"},
        "m_t": {"type": "array", "items": {"type": "number"}},
        "m_t1": {"type": "array", "items": {"type": "number"}},
        "s_t": {"type": "array", "items": {"type": "number"}, "description": "vector sensors only"},
        "s_t1": {"type": "array", "items": {"type": "number"}, "description": "vector sensors only"},
        "p_t": {"type": "array", "items": {"type": "number"}, "description": "privileged"},
        "p_t1": {"type": "array", "items": {"type": "number"}, "description": "privileged"},
        "shift_t": {"type": "array", "items": {"type": "number"}, "description": "privileged"},
        "shift_t1": {"type": "array", "items": {"type": "number"}, "description": "privileged"},
    },
}


def _foxglove(ds: Dataset, out: Path, limit: int | None) -> int:
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from mcap.writer import CompressionType, Writer
    from mcap_protobuf.schema import build_file_descriptor_set

    count = 0
    with atomic_writer(out) as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start(profile="", library="smspace export")
        writer.add_metadata("smspace.manifest", {"json": ds.manifest.to_json()})

        def channel(topic: str, cls) -> int:
            sid = writer.register_schema(
                cls.DESCRIPTOR.full_name, "protobuf", build_file_descriptor_set(cls).SerializeToString()
            )
            return writer.register_channel(topic, "protobuf", sid)

        json_schema = writer.register_schema(
            "smspace.Transition", "jsonschema", json.dumps(TRANSITION_JSON_SCHEMA).encode()
        )
        transition_ch = writer.register_channel("/transition", "json", json_schema)
        pose_ch = {name: channel(f"/{name}", PoseInFrame) for name in ("p_t", "p_t1")}
        images = ds.manifest.sensor_dtype == "uint8"
        image_ch = {name: channel(f"/{name}", RawImage) for name in ("s_t", "s_t1")} if images else {}
        for block in _blocks(ds, limit):
            first, tr = block.first_index, block.transitions
            for i in range(len(tr)):
                index = first + i
                t = EPOCH_NS + index * STEP_NS
                sec, nsec = divmod(t, 10**9)
                record = {"index": index}
                for name in ("m_t", "m_t1", "p_t", "p_t1", "shift_t", "shift_t1") + (() if images else ("s_t", "s_t1")):
                    record[name] = getattr(tr, name)[i].tolist()
                writer.add_message(transition_ch, log_time=t, publish_time=t, data=json.dumps(record).encode())
                for name, ch in pose_ch.items():
                    pose = PoseInFrame(frame_id="base")
                    pose.timestamp.seconds, pose.timestamp.nanos = sec, nsec
                    x, y = getattr(tr, name)[i]
                    pose.pose.position.x, pose.pose.position.y = float(x), float(y)
                    pose.pose.orientation.w = 1.0
                    writer.add_message(ch, log_time=t, publish_time=t, data=pose.SerializeToString())
                for name, ch in image_ch.items():
                    frame = getattr(tr, name)[i]
                    h, w, _ = frame.shape
                    img = RawImage(
                        frame_id="sensor", width=w, height=h, encoding="rgb8", step=3 * w, data=frame.tobytes()
                    )
                    img.timestamp.seconds, img.timestamp.nanos = sec, nsec
                    writer.add_message(ch, log_time=t, publish_time=t, data=img.SerializeToString())
            count += len(tr)
        writer.finish()
    return count


# -- parquet -------------------------------------------------------------------------------------
def _fixed(x: np.ndarray) -> pa.Array:
    x = np.ascontiguousarray(x)
    if x.dtype == np.uint8:  # images: one fixed-size binary per frame (3× smaller and faster than lists)
        return pa.FixedSizeBinaryArray.from_buffers(pa.binary(x[0].size), len(x), [None, pa.py_buffer(x.tobytes())])
    return parquet.fixed_list(x)


def transitions_table(first: int, tr: Transitions) -> pa.Table:
    columns = {"index": pa.array(np.arange(first, first + len(tr), dtype=np.uint64))}
    for name, column in tr.columns().items():
        columns[name] = _fixed(column)
    return pa.table(columns)


def _parquet(ds: Dataset, out: Path, limit: int | None) -> int:
    count = 0
    meta = {b"smspace.manifest": ds.manifest.to_json().encode()}
    with atomic_writer(out) as fh:
        writer = None
        try:
            for block in _blocks(ds, limit):
                table = transitions_table(block.first_index, block.transitions)
                if writer is None:
                    writer = pq.ParquetWriter(
                        fh, table.schema.with_metadata(meta), compression="zstd", use_dictionary=False
                    )
                writer.write_table(table.replace_schema_metadata(meta), row_group_size=65536)
                count += len(block.transitions)
        finally:  # also on a failed read, before atomic_writer drops the file: else the writer's
            if writer is not None:  # __del__ later writes to a closed file
                writer.close()
    return count


def read_parquet_transitions(path: Path) -> tuple[np.ndarray, Transitions, dict]:
    """Read an exported Parquet file back into numpy (the inverse of the export)."""
    table = parquet.read_table(Path(path))
    manifest = json.loads(table.schema.metadata[b"smspace.manifest"])
    shape = tuple(manifest["sensor_shape"])

    def col(name: str) -> np.ndarray:
        arr = table[name].combine_chunks()
        if pa.types.is_fixed_size_binary(arr.type):
            return np.frombuffer(arr.buffers()[1], np.uint8)[: len(arr) * arr.type.byte_width].reshape(len(arr), *shape)
        out = parquet.from_fixed_list(arr)
        return out.reshape(len(arr), *shape) if name in ("s_t", "s_t1") else out

    tr = Transitions(**{name: col(name) for name in COLUMNS})
    return table["index"].to_numpy(), tr, manifest
