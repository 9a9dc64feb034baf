"""Write files so that a crash leaves either the old file or the complete new one, never a mix."""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from smspace.common.errors import SmspaceError

PARTIAL_SUFFIX = ".partial"  # of every file smspace writes before it has its final name


def partial_path(path: Path) -> Path:
    """Where `path` is written until it is complete: beside it, named by this process."""
    return path.with_name(f"{path.name}.{os.getpid()}{PARTIAL_SUFFIX}")


def commit(partial: Path, path: Path) -> None:
    """Give a complete partial file its final name, durably; on failure nothing is left."""
    try:
        with open(partial, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(partial, path)
        fsync_dir(path.parent)
    except OSError as e:
        partial.unlink(missing_ok=True)
        raise SmspaceError(f"cannot write {path}: {e.strerror or e}") from e


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_writer(path: Path) -> Iterator[BinaryIO]:
    """Yield a file that becomes `path` only if the block completes; on error nothing is left."""
    tmp = partial_path(path)
    try:
        with open(tmp, "wb") as fh:
            yield fh
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise SmspaceError(f"cannot write {path}: {e.strerror or e}") from e
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    commit(tmp, path)


def write_atomic(path: Path, data: bytes) -> None:
    with atomic_writer(path) as fh:
        fh.write(data)


def create_exclusive(path: Path, data: bytes) -> None:
    """Write `path` only if it does not exist (FileExistsError otherwise), complete or not at all:
    the data goes to a temporary file, then a hard link claims the final name, which fails if it
    is taken; two writers racing for the name cannot both succeed."""
    tmp = partial_path(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.link(tmp, path)
        fsync_dir(path.parent)
    except FileExistsError:
        raise
    except OSError as e:
        raise SmspaceError(f"cannot write {path}: {e.strerror or e}") from e
    finally:
        tmp.unlink(missing_ok=True)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def remove_partials(folder: Path) -> None:
    """Drop what killed writers left behind; their final names were never created."""
    for p in folder.glob(f"*{PARTIAL_SUFFIX}"):
        p.unlink(missing_ok=True)
