"""MCAP shards of column-wise transition batches, and the regular-sampling file.

Every file embeds its protobuf schema (a FileDescriptorSet), so any MCAP tool can decode it.
Each batch message is its own zstd chunk: the chunk index then addresses batches directly,
which is what readers use to split work and to seek.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.reader import SeekingReader, make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from smspace import schemas
from smspace.common.errors import DatasetCorrupt, SmspaceError, one_line
from smspace.lake.store import Store, TransferFailed, damaged_transfer
from smspace.lake.transitions import Transitions

CHUNK_PREFIX = 1 + 8  # a chunk record's opcode and length, before its content
CHUNK_READS = 3  # a chunk failing its CRC is read again this often before anything is concluded

TRANSITIONS_TOPIC = "/transitions"
REGULAR_TOPIC = "/regular_sampling"
SHARD_METADATA = "smspace.shard"
LIBRARY = "smspace"


@dataclass(frozen=True)
class Block:
    """A decoded batch message: transitions first_index .. first_index + len(transitions) - 1."""

    first_index: int
    transitions: Transitions
    # walks (schema version 2): each transition's episode and step index; None: transitions
    episode: np.ndarray | None = None
    step: np.ndarray | None = None

    @property
    def version(self) -> int:
        return schemas.TRANSITIONS_VERSION if self.episode is None else schemas.WALKS_VERSION

    def head(self, n: int) -> Block:
        """The block's first n transitions, with their episode and step indices."""
        cut = lambda x: None if x is None else x[:n]  # noqa: E731
        return Block(self.first_index, self.transitions[:n], cut(self.episode), cut(self.step))


def _sensor_column(column: schemas.transitions_pb2.SensorColumn, s: np.ndarray) -> None:
    if s.dtype == np.uint8:
        column.uint8 = np.ascontiguousarray(s).tobytes()
    else:
        column.float32.values.extend(s.reshape(-1).astype(np.float32))


def encode_batch(first_index: int, tr: Transitions, episode: np.ndarray | None = None,
                 step: np.ndarray | None = None) -> bytes:  # fmt: skip
    """Version 1 for transitions (the bytes they always had), version 2 with episodes for walks."""
    version = schemas.TRANSITIONS_VERSION if episode is None else schemas.WALKS_VERSION
    msg = schemas.VERSIONS[version].TransitionBatch(
        schema_version=version,
        first_index=first_index,
        count=len(tr),
        motor_dim=tr.m_t.shape[1],
        sensor_shape=tr.s_t.shape[1:],
    )
    msg.m_t.extend(tr.m_t.reshape(-1))
    msg.m_t1.extend(tr.m_t1.reshape(-1))
    _sensor_column(msg.s_t, tr.s_t)
    _sensor_column(msg.s_t1, tr.s_t1)
    priv = msg.privileged
    priv.p_t.extend(tr.p_t.reshape(-1))
    priv.p_t1.extend(tr.p_t1.reshape(-1))
    priv.shift_t.extend(tr.shift_t.reshape(-1))
    priv.shift_t1.extend(tr.shift_t1.reshape(-1))
    if episode is not None:
        if step is None or len(episode) != len(tr) or len(step) != len(tr):
            raise ValueError(f"{len(tr)} transitions need as many episode and step indices")
        msg.episodes.episode.extend(np.asarray(episode, np.uint64))
        msg.episodes.step.extend(np.asarray(step, np.uint32))
    return msg.SerializeToString()


def _sensor_array(column: schemas.transitions_pb2.SensorColumn, shape: tuple[int, ...]) -> np.ndarray:
    kind = column.WhichOneof("values")
    if kind == "uint8":
        return np.frombuffer(column.uint8, np.uint8).reshape(shape)
    if kind == "float32":
        return np.array(column.float32.values, np.float32).reshape(shape)
    raise ValueError("sensor column is empty")


def decode_batch(data: bytes) -> Block:
    """Either version: version 2's message reads version 1's bytes (it only adds `episodes`)."""
    msg = schemas.VERSIONS[schemas.WALKS_VERSION].TransitionBatch.FromString(data)
    if msg.schema_version not in schemas.READABLE:
        raise ValueError(f"batch of schema version {msg.schema_version}")
    n, nm = msg.count, msg.motor_dim
    shape = (n, *msg.sensor_shape)
    priv = msg.privileged

    def f32(values, width: int) -> np.ndarray:
        return np.array(values, np.float32).reshape(n, width)

    tr = Transitions(
        m_t=f32(msg.m_t, nm),
        m_t1=f32(msg.m_t1, nm),
        s_t=_sensor_array(msg.s_t, shape),
        s_t1=_sensor_array(msg.s_t1, shape),
        p_t=f32(priv.p_t, 2),
        p_t1=f32(priv.p_t1, 2),
        shift_t=f32(priv.shift_t, 2),
        shift_t1=f32(priv.shift_t1, 2),
    )
    if msg.schema_version == schemas.TRANSITIONS_VERSION:
        if msg.HasField("episodes"):
            raise ValueError("a batch of schema version 1 carries episodes")
        return Block(msg.first_index, tr)
    episode = np.array(msg.episodes.episode, np.int64)
    step = np.array(msg.episodes.step, np.int64)
    if len(episode) != n or len(step) != n:
        raise ValueError(f"batch of {n} transitions has {len(episode)} episode and {len(step)} step indices")
    return Block(msg.first_index, tr, episode, step)


def _start_writer(fh, schema_name: str, message_class, topic: str) -> tuple[Writer, int]:
    # chunk_size=1: every message closes its own chunk, so the chunk index addresses batches.
    writer = Writer(fh, compression=CompressionType.ZSTD, chunk_size=1)
    writer.start(profile="", library=LIBRARY)
    fds = build_file_descriptor_set(message_class).SerializeToString()
    schema_id = writer.register_schema(schema_name, "protobuf", fds)
    channel_id = writer.register_channel(topic, "protobuf", schema_id)
    return writer, channel_id


def shard_bytes(blocks: Sequence[Block], metadata: dict[str, str]) -> bytes:
    """A whole shard in memory: it is stored in one step (a rename locally, one PUT on S3)."""
    versions = {block.version for block in blocks} or {schemas.TRANSITIONS_VERSION}
    if len(versions) > 1:
        raise ValueError("a shard holds walks or transitions, not both")
    (version,) = versions
    fh = io.BytesIO()
    message_class = schemas.VERSIONS[version].TransitionBatch
    writer, channel = _start_writer(fh, schemas.transition_batch_name(version), message_class, TRANSITIONS_TOPIC)
    writer.add_metadata(SHARD_METADATA, metadata)
    for seq, block in enumerate(blocks):
        t = block.first_index  # log_time = transition index, so time ranges select transitions
        data = encode_batch(t, block.transitions, block.episode, block.step)
        writer.add_message(channel, log_time=t, publish_time=t, data=data, sequence=seq)
    writer.finish()
    return fh.getvalue()


def regular_sampling_bytes(m: np.ndarray, p: np.ndarray) -> bytes:
    msg = schemas.RegularSampling(schema_version=schemas.SCHEMA_VERSION, count=len(m), motor_dim=m.shape[1])
    msg.m.extend(m.astype(np.float32).reshape(-1))
    msg.p.extend(p.astype(np.float32).reshape(-1))
    fh = io.BytesIO()
    writer, channel = _start_writer(fh, schemas.REGULAR_SAMPLING, schemas.RegularSampling, REGULAR_TOPIC)
    writer.add_message(channel, log_time=0, publish_time=0, data=msg.SerializeToString(), sequence=0)
    writer.finish()
    return fh.getvalue()


class ShardReader:
    """Reads one shard; keep one open per shard and worker (re-reading the summary is costly).

    The summary comes down once; then each batch is one ranged read of its chunk, located by the
    chunk index (one request per batch on object storage, never a whole-shard download)."""

    def __init__(self, store: Store | None, name: str, validate_crcs: bool = True, data: bytes | None = None):
        """A shard of a folder (`store`), read by ranges; or, with `data`, its bytes already fetched
        (`from_bytes`)."""
        self.store, self.name, self._data = store, name, data
        self.path = name if store is None else f"{store.url}/{name}"  # for messages
        self._validate_crcs = validate_crcs
        for attempt in range(CHUNK_READS):  # the summary, read again when the transfer failed
            try:
                self._fh = io.BytesIO(data) if data is not None else store.open(name)
            except FileNotFoundError:
                raise SmspaceError(f"missing shard {self.path}") from None
            try:
                self._reader: SeekingReader = make_reader(self._fh, validate_crcs=validate_crcs)
                summary = self._reader.get_summary()
                break
            except Exception as e:  # what mcap, zstd or protobuf raise on bad bytes is corruption…
                self._fh.close()
                transfer = damaged_transfer(e)  # …but a connection cut or garbled on the way is not
                if transfer is None:
                    raise DatasetCorrupt(f"corrupt shard {self.path}: {one_line(e, with_type=True)}") from e
                if attempt == CHUNK_READS - 1:
                    raise TransferFailed(f"{self.path}: the transfer failed {CHUNK_READS} times ({transfer})") from None
        if summary is None:
            self._fh.close()
            raise DatasetCorrupt(f"corrupt shard {self.path}: no summary (truncated?)")
        self.summary = summary
        names = {s.name for s in summary.schemas.values()}
        readable = [{schemas.transition_batch_name(v)} for v in schemas.READABLE] + [{schemas.REGULAR_SAMPLING}]
        if names not in readable:
            self._fh.close()
            versions = ", ".join(f"{v} ({schemas.package(v)})" for v in schemas.READABLE)
            raise SmspaceError(
                f"shard {self.path} has schema {', '.join(sorted(names))}; "
                f"this smspace reads schema versions {versions}"
            )

    @classmethod
    def from_bytes(cls, data: bytes, where: str, validate_crcs: bool = True) -> ShardReader:
        """A shard whose bytes are in memory (`where` names it in messages): validate reads each
        file once, whole, and checks it from there."""
        return cls(None, where, validate_crcs, data)

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> ShardReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def metadata(self) -> dict[str, str]:
        try:
            for record in self._reader.iter_metadata():
                if record.name == SHARD_METADATA:
                    return dict(record.metadata)
        except Exception as e:
            raise DatasetCorrupt(f"corrupt shard {self.path}: {one_line(e, with_type=True)}") from e
        return {}

    def stats(self) -> dict[str, list[float]]:
        return json.loads(self.metadata().get("stats", "{}"))

    def _chunk(self, offset: int, length: int) -> bytes:
        start, n = offset + CHUNK_PREFIX, length - CHUNK_PREFIX
        if self._data is not None:
            return self._data[start : start + n]
        return self.store.read(self.name, start, n)

    def _raw(self, starting_at: int | None = None, ending_before: int | None = None) -> Iterator[bytes]:
        low = -1 if starting_at is None else starting_at
        high = float("inf") if ending_before is None else ending_before
        indexes = sorted(self.summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        for ci in indexes:
            if low <= ci.message_start_time < high:
                yield from (data for time, data in self._chunk_messages(ci) if low <= time < high)

    def _chunk_messages(self, ci) -> list[tuple[int, bytes]]:
        """(log time, data) of a chunk's messages. A chunk that fails its checks is fetched again:
        bytes that differ from one read to the next are a faulty transfer (retried), the same bad
        bytes twice are a corrupt shard."""
        seen: list[bytes] = []
        for _ in range(CHUNK_READS):
            data = self._chunk(ci.chunk_start_offset, ci.chunk_length)
            try:
                if len(data) != ci.chunk_length - CHUNK_PREFIX:
                    raise ValueError(f"chunk at {ci.chunk_start_offset} cut short")
                chunk = Chunk.read(ReadDataStream(io.BytesIO(data)))
                records = breakup_chunk(chunk, validate_crc=self._validate_crcs)
                return [(r.log_time, r.data) for r in records if isinstance(r, Message)]
            except SmspaceError:
                raise
            except Exception as e:
                if self._data is not None or data in seen:  # bytes in memory, or read twice alike: stored so
                    raise DatasetCorrupt(f"corrupt shard {self.path}: {one_line(e, with_type=True)}") from e
                seen.append(data)
        raise TransferFailed(
            f"{self.path}: the chunk at {ci.chunk_start_offset} arrived different on each of {CHUNK_READS} reads"
        )

    def blocks(self, starting_at: int | None = None, ending_before: int | None = None) -> Iterator[Block]:
        """Decoded batches in file order, optionally only those starting in [starting_at, ending_before)."""
        for data in self._raw(starting_at, ending_before):
            try:
                yield decode_batch(data)
            except Exception as e:  # a message that does not parse is corruption, whatever protobuf says
                raise DatasetCorrupt(
                    f"corrupt shard {self.path}: undecodable batch ({one_line(e, with_type=True)})"
                ) from e

    def block_at(self, first_index: int) -> Block:
        for block in self.blocks(first_index, first_index + 1):
            return block
        raise DatasetCorrupt(f"corrupt shard {self.path}: no batch starts at transition {first_index}")

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        for data in self._raw():
            try:
                msg = schemas.RegularSampling.FromString(data)
                m = np.array(msg.m, np.float32).reshape(msg.count, msg.motor_dim)
                return m, np.array(msg.p, np.float32).reshape(msg.count, 2)
            except Exception as e:
                raise DatasetCorrupt(f"corrupt regular sampling {self.path}: {one_line(e, with_type=True)}") from e
        raise DatasetCorrupt(f"corrupt regular sampling {self.path}: no message")
