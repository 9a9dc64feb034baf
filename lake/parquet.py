"""Parquet as smspace writes and reads it: small files held as bytes (metrics, catalogs, embeddings)
and exports, read so that no process ever aborts at exit, and vectors as fixed-size lists.

pyarrow's Parquet reader finishes its reads through futures on its own thread pool, and the last
reference to a reader may be dropped there after Python began to shut down. When the reader's
buffer belongs to Python (bytes wrapped by `pa.BufferReader`), freeing it takes the GIL; a
finalizing interpreter answers that by ending the thread, `pthread_exit` unwinds through a noexcept
C++ destructor, and the process aborts: "terminate called without an active exception", exit 134
(arrow::py::PyBuffer::~PyBuffer in an arrow ThreadPool worker, under PyGILState_Ensure). So the
bytes are first copied into memory Arrow owns (these files are small), and read without
pre-buffering or threads (tests/test_exit.py repeats the read that aborted)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def arrow_owned(data: bytes) -> pa.BufferReader:
    """A reader over a copy of `data` that Arrow owns: freeing it never needs Python."""
    sink = pa.BufferOutputStream()
    sink.write(data)
    return pa.BufferReader(sink.getvalue())


def read_table(data: bytes | Path) -> pa.Table:
    """The table in Parquet bytes, or in a Parquet file (an export), read the same safe way."""
    source = data if isinstance(data, Path) else arrow_owned(data)
    return pq.read_table(source, use_threads=False, pre_buffer=False)


def table_bytes(table: pa.Table) -> bytes:
    """A small table as Parquet bytes (zstd), for a store's `put`."""
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    return buf.getvalue()


def fixed_list(x: np.ndarray) -> pa.FixedSizeListArray:
    """Rows of float32 vectors (h, p, a transition's sensor values) as one fixed-size list each."""
    flat = np.ascontiguousarray(x, np.float32).reshape(len(x), -1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def from_fixed_list(column: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """The inverse of `fixed_list`: an array of shape (rows, width)."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    return arr.values.to_numpy().reshape(len(arr), arr.type.list_size)


def read_schema(data: bytes) -> pa.Schema:
    return pq.read_schema(arrow_owned(data))
