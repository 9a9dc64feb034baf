"""What a result carries so that its scores can be derived again by anyone: for each world and mode,
h of the task's regular states as a .npy file (numpy's own format, read without pickle) in the
result's `evidence/` folder, its sha256 in scores.json. The positions p are never taken from the
result: they come from the task's setup and world seed (the regular sampling every dataset of the
world records, float32 as stored), so a forged h cannot come with positions to match it.
"""

from __future__ import annotations

import hashlib
import io
from functools import cache

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.lake.store import Store

EVIDENCE = "evidence"
DTYPES = ("<f8", "<f4")  # h as the run gave it: float64 (isomap, an ensemble's evaluation) or float32


def file_of(world: int, mode: str, step: int | None = None) -> str:
    """The last evaluation's h, or (step) an earlier evaluation's."""
    return f"h-{world}-{mode}.npy" if step is None else f"h-{world}-{mode}-step{step}.npy"


def npy_bytes(h: np.ndarray) -> bytes:
    """h as float32 where that loses nothing (a network's h is float32, whatever carried it since),
    else float64 (isomap's): half the bytes for every learned entry, the same values read back."""
    h = np.ascontiguousarray(h, np.float64)
    single = h.astype(np.float32)
    out = io.BytesIO()
    np.save(out, single if np.array_equal(single.astype(np.float64), h) else h, allow_pickle=False)
    return out.getvalue()


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def save(folder: Store, world: int, mode: str, h: np.ndarray, step: int | None = None) -> tuple[str, str]:
    """Writes h; returns (its file name, its sha256)."""
    data = npy_bytes(h)
    evidence = folder.child(EVIDENCE)
    evidence.make()
    evidence.put(file_of(world, mode, step), data)
    return file_of(world, mode, step), sha256(data)


def load(folder: Store, name: str, digest: str, shape: tuple[int, int]) -> np.ndarray:
    """h of one world and mode, checked before use: the file is a plain .npy no larger than an
    array of `shape` needs, of that shape and a float dtype, with the sha256 scores.json names."""
    where = f"{folder.url}/{EVIDENCE}/{name}"
    evidence = folder.child(EVIDENCE)
    limit = shape[0] * shape[1] * 8 + 4096
    try:
        size = evidence.size(name)
        if size > limit:
            raise SmspaceError(f"{where}: {size} bytes, more than h of {shape[0]} states x {shape[1]} needs")
        data = evidence.read(name)
    except FileNotFoundError:
        raise SmspaceError(f"{where} is missing: the result carries no evidence for its scores") from None
    except OSError as e:
        raise SmspaceError(f"{where} cannot be read ({e})") from None
    if sha256(data) != digest:
        raise SmspaceError(f"{where} is not the file scores.json names (its sha256 differs)")
    fh = io.BytesIO(data)
    try:
        major, _ = np.lib.format.read_magic(fh)
        read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        found, fortran, dtype = read(fh, max_header_size=1024)
    except (ValueError, OSError) as e:
        raise SmspaceError(f"{where} is not a .npy array ({e})") from None
    if found != shape or fortran or dtype.str not in DTYPES:
        raise SmspaceError(
            f"{where} holds a {dtype.str} array of shape {found}; h of this task is {shape} float32 or float64"
        )
    fh.seek(0)
    return np.load(fh, allow_pickle=False).astype(np.float64)


@cache
def positions(setup: str, world: int) -> np.ndarray:
    """The sensor positions of the regular states, as generation stores them (float32)."""
    from smspace.datagen.parts import world_for

    _, p = world_for(setup, world).regular_sampling()
    return np.asarray(p, np.float32).astype(np.float64)
