"""Small Parquet files held as bytes (metrics, catalogs, embeddings), read so that no process ever
aborts at exit.

pyarrow's Parquet reader finishes its reads through futures on its own thread pool, and the last
reference to a reader may be dropped there after Python began to shut down. When the reader's
buffer belongs to Python (bytes wrapped by `pa.BufferReader`), freeing it takes the GIL; a
finalizing interpreter answers that by ending the thread, `pthread_exit` unwinds through a noexcept
C++ destructor, and the process aborts: "terminate called without an active exception", exit 134
(4 exits in 20 of `smspace.open_run(R).metrics()`; seen in gdb: arrow::py::PyBuffer::~PyBuffer in
an arrow ThreadPool worker, under PyGILState_Ensure). So the bytes are first copied into memory
Arrow owns (these files are small), and read without pre-buffering or threads."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq


def arrow_owned(data: bytes) -> pa.BufferReader:
    """A reader over a copy of `data` that Arrow owns: freeing it never needs Python."""
    sink = pa.BufferOutputStream()
    sink.write(data)
    return pa.BufferReader(sink.getvalue())


def read_table(data: bytes) -> pa.Table:
    return pq.read_table(arrow_owned(data), use_threads=False, pre_buffer=False)


def read_schema(data: bytes) -> pa.Schema:
    return pq.read_schema(arrow_owned(data))
