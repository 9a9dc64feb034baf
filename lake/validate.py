"""`smgen validate`: check a dataset against its manifest, the schema and its mode's invariant."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smspace import schemas
from smspace.common.errors import SmspaceError
from smspace.lake.episodes import episode_problem
from smspace.lake.exploration import Exploration
from smspace.lake.integrity import content_problem, read_verified
from smspace.lake.manifest import load_manifest
from smspace.lake.shards import Block, ShardReader
from smspace.lake.store import StorageUnreachable, Store, etag, open_store
from smspace.lake.transitions import Transitions


class _ModeCheck:
    """Accumulates what the mode invariant needs over all shards (docs/MODEL.md §1)."""

    def __init__(self, mode: str):
        self.mode = mode
        self.first_shift: np.ndarray | None = None
        self.n = 0
        self.equal = 0
        self.sums = np.zeros((5, 2))  # Σa, Σb, Σa², Σb², Σab per axis (MEM independence)

    def add(self, shift_t: np.ndarray, shift_t1: np.ndarray) -> str | None:
        if self.first_shift is None and len(shift_t):
            self.first_shift = shift_t[0].copy()
        same = np.all(shift_t == shift_t1, axis=1)
        if self.mode == "MM" and (not same.all() or not np.all(shift_t == self.first_shift)):
            return "MM shift is not one constant value"
        if self.mode == "MME" and not same.all():
            return f"MME shift_t != shift_t1 in {int((~same).sum())} transitions"
        a, b = shift_t.astype(np.float64), shift_t1.astype(np.float64)
        self.sums += np.stack([a.sum(0), b.sum(0), (a * a).sum(0), (b * b).sum(0), (a * b).sum(0)])
        self.n += len(a)
        self.equal += int(same.sum())
        return None

    def finish(self) -> str | None:
        if self.mode != "MEM" or self.n < 2:
            return None
        sa, sb, saa, sbb, sab = self.sums / self.n
        corr = (sab - sa * sb) / np.sqrt(np.maximum((saa - sa**2) * (sbb - sb**2), 1e-30))
        limit = max(0.05, 5 / np.sqrt(self.n))
        if np.any(np.abs(corr) > limit) or self.equal / self.n > 0.05:
            return (
                f"MEM shifts are not independent (correlation {np.round(corr, 3).tolist()}, "
                f"{self.equal}/{self.n} transitions with shift_t == shift_t1)"
            )
        return None


class _EpisodeCheck:
    """The walk invariants (lake/episodes.py) of one shard, block by block: each block is checked
    with the last transition of the block before it, so an episode broken at a seam is found."""

    def __init__(self, mode: str, length: int):
        self.mode, self.length = mode, length
        self.last: Block | None = None

    def add(self, block: Block) -> str | None:
        if block.episode is None or block.step is None:
            return f"batch at {block.first_index} has no episode indices (a walk's schema version 2 carries them)"
        if len(block.step) and int(block.step.max()) >= self.length:
            return f"batch at {block.first_index} has step {int(block.step.max())} in episodes of {self.length} steps"
        head, carried = block, self.last is not None
        if carried:
            t = Transitions(*(np.concatenate([getattr(self.last.transitions, f)[-1:], getattr(block.transitions, f)])
                              for f in Transitions.__dataclass_fields__))  # fmt: skip
            head = Block(block.first_index - 1, t, np.concatenate([self.last.episode[-1:], block.episode]),
                         np.concatenate([self.last.step[-1:], block.step]))  # fmt: skip
        self.last = block
        return episode_problem(head.transitions, head.episode, head.step, self.mode, head.first_index, carried)


def _batch_problems(tr, bound: float | None, mode: str) -> list[str]:
    problems = []
    for name in ("m_t", "m_t1", "s_t", "s_t1", "p_t", "p_t1", "shift_t", "shift_t1"):
        arr = getattr(tr, name)
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            problems.append(f"{name} has NaN or inf")
    for name in ("m_t", "m_t1"):
        arr = getattr(tr, name)
        if np.any(np.abs(arr) > 1.0):
            problems.append(f"{name} outside [-1, 1]")
    if mode != "MM" and bound is not None:
        for name in ("shift_t", "shift_t1"):
            if np.any(np.abs(getattr(tr, name)) > bound):
                problems.append(f"{name} outside ±{bound}")
    return problems


def _fetch(folder: Store, entry: dict) -> tuple[bytes | None, list[str]]:
    """A file's bytes, fetched whole (one download on object storage; again only when they do not
    match the manifest, lake/integrity.py) with what is wrong with them; None and why if unread."""
    try:
        name, md5 = entry["file"], entry.get("md5")
        vouched = lambda: md5 is not None and etag(folder, name) == md5  # noqa: E731 - the store's witness
        data, problem = read_verified(folder, name, lambda d: content_problem(d, entry), vouched)
    except FileNotFoundError:
        return None, ["missing"]
    except StorageUnreachable:
        raise
    except SmspaceError as e:
        return None, [str(e)]
    return data, [problem] if problem else []


def validate_dataset(folder: Store | Path) -> list[str]:
    """Every problem found, one line each, naming the file; empty when the dataset is sound. Each
    file is fetched once and checked from memory: sha256, every chunk CRC, every batch."""
    folder = open_store(folder)
    try:
        manifest = load_manifest(folder)
    except StorageUnreachable:
        raise
    except SmspaceError as e:
        return [str(e)]
    problems: list[str] = []
    mode_check = _ModeCheck(manifest.mode)
    expected_index = 0
    walk = Exploration.from_record(manifest.config.get("exploration"))
    for shard in manifest.shards:
        episodes = _EpisodeCheck(manifest.mode, walk.length) if walk.walks else None
        where = f"{folder.name}/{shard['file']}"
        data, found = _fetch(folder, shard)
        problems += [f"{where}: {problem}" for problem in found]
        if data is None:
            continue
        expected_index = shard["first_index"]
        count = 0
        try:
            with ShardReader.from_bytes(data, f"{folder.url}/{shard['file']}") as reader:
                for block in reader.blocks():
                    tr = block.transitions
                    if block.first_index != expected_index:
                        problems.append(f"{where}: batch starts at {block.first_index}, expected {expected_index}")
                    if tr.m_t.shape[1] != manifest.n_motor or list(tr.s_t.shape[1:]) != manifest.sensor_shape:
                        problems.append(f"{where}: batch shapes differ from the manifest")
                    expected_index = block.first_index + len(tr)
                    count += len(tr)
                    problems += [f"{where}: {p}" for p in _batch_problems(tr, manifest.shift_bound, manifest.mode)]
                    issue = mode_check.add(tr.shift_t, tr.shift_t1)
                    if issue:
                        problems.append(f"{where}: {issue}")
                    if block.version != manifest.schema_version:
                        version = f"schema version {block.version} in a dataset of {manifest.schema_version}"
                        problems.append(f"{where}: a batch of {version}")
                    elif episodes is not None and (issue := episodes.add(block)):
                        problems.append(f"{where}: {issue}")
        except StorageUnreachable:
            raise
        except SmspaceError as e:
            problems.append(f"{where}: {e}")
            continue
        if count != shard["transitions"]:
            problems.append(f"{where}: {count} transitions, manifest says {shard['transitions']}")
    total = sum(s["transitions"] for s in manifest.shards)
    if total != manifest.transitions:
        problems.append(f"{folder.name}: shards hold {total} transitions, manifest says {manifest.transitions}")
    issue = mode_check.finish()
    if issue:
        problems.append(f"{folder.name}: {issue}")
    problems += _regular_problems(folder, manifest)
    if manifest.schema_version not in schemas.READABLE:
        problems.append(f"{folder.name}: schema version {manifest.schema_version}")
    return _dedupe(problems)


def _regular_problems(folder: Store, manifest) -> list[str]:
    reg = manifest.regular_sampling
    where = f"{folder.name}/{reg['file']}"
    data, found = _fetch(folder, reg)
    if data is None or found:
        return [f"{where}: {problem}" for problem in found]
    try:
        with ShardReader.from_bytes(data, f"{folder.url}/{reg['file']}") as reader:
            m, _ = reader.regular_sampling()
    except StorageUnreachable:
        raise
    except SmspaceError as e:
        return [f"{where}: {e}"]
    return [] if len(m) == reg["count"] else [f"{where}: {len(m)} samples, manifest says {reg['count']}"]


def _dedupe(lines: list[str]) -> list[str]:
    """Repeated per-batch findings collapse to one line each."""
    seen: dict[str, None] = {}
    for line in lines:
        seen.setdefault(line, None)
    return list(seen)
