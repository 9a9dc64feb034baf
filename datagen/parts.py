"""The parts of a dataset: its shards and its regular-sampling file, each a pure function of the
config, written whole in one step and checked whole before it is kept.

Shard i draws from SeedSequence(world_seed, spawn_key=(1, mode, i)), so its bytes do not depend on
the executor, the worker count or on which shards an interrupted run had already written. Every
function here runs wherever the executor puts it (a local process, a Ray worker, a SLURM task) and
returns a `PartRecord`, what the commit needs to write the manifest without reading the part again.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.datagen.setups import MODES, World, draw_transitions, get_setup, setup_label, setup_plugin
from smspace.datagen.setups.contract import check_block, check_regular, check_world, declared
from smspace.datagen.walks import draw_walks
from smspace.lake.manifest import REGULAR_FILE, GenConfig, shard_name, software_versions
from smspace.lake.shards import Block, ShardReader, regular_sampling_bytes, shard_bytes
from smspace.lake.store import StorageUnreachable, Store

REGULAR = -1  # the part number of the regular-sampling file; shards are 0 .. n_shards - 1
_WORLDS: dict[tuple[str, int], World] = {}


@dataclass(frozen=True)
class PartRecord:
    """A part as stored: what the manifest records of it, and the shapes the commit checks."""

    part: int
    file: str
    bytes: int
    sha256: str
    md5: str  # what object storage reports as the ETag of a single PUT: a cheap witness on reads
    count: int  # transitions (a shard) or samples (the regular file)
    stats: dict[str, list[float]] | None  # m/s min and max (shards only)
    n_motor: int
    sensor_shape: tuple[int, ...] | None  # shards only
    sensor_dtype: str | None
    # what made the bytes, where they were made (a Ray worker's SAPIEN and GPU may not be ours);
    # None for a part found already stored, written by an earlier command
    software: dict[str, str] | None = None

    @classmethod
    def of(cls, part: int, data: bytes, count: int, n_motor: int, **shard: Any) -> PartRecord:
        """The record of a part's bytes; `shard`: stats, sensor_shape and sensor_dtype of a shard."""
        digests = hashlib.sha256(data).hexdigest(), hashlib.md5(data, usedforsecurity=False).hexdigest()
        fields = {"stats": None, "sensor_shape": None, "sensor_dtype": None, "software": None} | shard
        return cls(part, part_file(part), len(data), *digests, count, n_motor=n_motor, **fields)

    def entry(self) -> dict[str, Any]:
        """What the manifest records of the file."""
        return {"file": self.file, "bytes": self.bytes, "sha256": self.sha256, "md5": self.md5}


def world_for(setup: str, seed: int) -> World:
    """One world per (setup, seed) per process: building the SAPIEN room is not free."""
    key = (setup, seed)
    if key not in _WORLDS:
        with plugins.guarded(setup_plugin(setup), f"building world {seed}"):
            _WORLDS[key] = get_setup(setup).build(seed)
    return _WORLDS[key]


def shard_rng(cfg: GenConfig, i: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(cfg.world_seed, spawn_key=(1, MODES.index(cfg.mode), i)))


def part_file(part: int) -> str:
    return REGULAR_FILE if part == REGULAR else shard_name(part)


def parts_of(cfg: GenConfig) -> list[int]:
    return [*range(cfg.n_shards), REGULAR]


def _stats(blocks: list[Block]) -> dict[str, list[float]]:
    m = np.concatenate([b.transitions.m_t for b in blocks])
    s = np.concatenate([b.transitions.s_t.reshape(len(b.transitions), -1) for b in blocks])
    return {
        "m_min": m.min(0).astype(float).tolist(),
        "m_max": m.max(0).astype(float).tolist(),
        "s_min": s.min(0).astype(float).tolist(),
        "s_max": s.max(0).astype(float).tolist(),
    }


def _shard_record(part: int, data: bytes, blocks: list[Block], stats: dict[str, list[float]]) -> PartRecord:
    tr = blocks[0].transitions
    return PartRecord.of(
        part,
        data,
        sum(len(b.transitions) for b in blocks),
        int(tr.m_t.shape[1]),
        stats=stats,
        sensor_shape=tuple(int(d) for d in tr.s_t.shape[1:]),
        sensor_dtype=tr.s_t.dtype.name,
    )


@dataclass(frozen=True)
class _PendingBlock:
    """One block still to draw: what it holds, for an error's words, and how to draw it."""

    what: str
    draw: Callable[[], Block]


def _transition_blocks(
    cfg: GenConfig, world: World, rng: np.random.Generator, lo: int, hi: int
) -> Iterator[_PendingBlock]:
    for start in range(lo, hi, cfg.batch_size):
        n = min(cfg.batch_size, hi - start)
        yield _PendingBlock("transitions", lambda s=start, n=n: Block(s, draw_transitions(world, cfg.mode, rng, n)))


def _walk_blocks(cfg: GenConfig, world: World, rng: np.random.Generator, lo: int, hi: int) -> Iterator[_PendingBlock]:
    """Whole episodes per block (about batch_size transitions): an episode's index is its first
    transition's index over the length, so a shard's episodes follow from its range alone."""
    walk = cfg.explored
    per_block = walk.block_transitions(cfg.batch_size) // walk.length
    for first in range(lo // walk.length, hi // walk.length, per_block):
        n = min(per_block, hi // walk.length - first)

        def draw(first: int = first, n: int = n) -> Block:
            w = draw_walks(world, cfg.mode, rng, n, walk.length, walk.step)
            return Block(first * walk.length, w.transitions, w.episode + first, w.step)

        yield _PendingBlock("walks", draw)


def write_part(cfg: GenConfig, folder: Store, part: int) -> PartRecord:
    """Draw and store one part (a shard, or the regular sampling when part == REGULAR)."""
    world = world_for(cfg.setup, cfg.world_seed)
    spec, plugin = get_setup(cfg.setup), setup_plugin(cfg.setup)
    where = f"{setup_label(cfg.setup)}, dataset {cfg.dataset_id}, {part_file(part)}"
    declares = declared(spec, world, where)
    if part == REGULAR:
        with plugins.guarded(plugin, f"in regular_sampling() of world {cfg.world_seed}"):
            m, p = world.regular_sampling()
        check_regular(m, p, declares[0], where)
        data = regular_sampling_bytes(m, p)
        folder.put(REGULAR_FILE, data)
        return PartRecord.of(part, data, len(m), m.shape[1], software=made_with(cfg.setup))
    rng = shard_rng(cfg, part)
    lo, hi = cfg.shard_range(part)
    draw = _walk_blocks if cfg.explored.walks else _transition_blocks
    blocks = []
    for block in draw(cfg, world, rng, lo, hi):
        with plugins.guarded(plugin, f"drawing {block.what} of world {cfg.world_seed} ({cfg.mode})"):
            made = block.draw()
        last = made.first_index + len(made.transitions) - 1
        check_block(made.transitions, declares, f"{where}, transitions {made.first_index}..{last}")
        blocks.append(made)
    stats = _stats(blocks)
    metadata = {
        "dataset_id": cfg.dataset_id,
        "shard_index": str(part),
        "first_index": str(lo),
        "transitions": str(hi - lo),
        "config_hash": cfg.config_hash,
        "stats": json.dumps(stats),
    }
    data = shard_bytes(blocks, metadata)
    folder.put(shard_name(part), data)
    return replace(_shard_record(part, data, blocks, stats), software=made_with(cfg.setup))


def verify_part(cfg: GenConfig, folder: Store, part: int) -> PartRecord | None:
    """The record of a part found under its final name, or None unless it belongs to cfg and reads
    back whole: every chunk CRC checked and every batch decoded, so a damaged part is redone."""
    name = part_file(part)
    try:
        data = folder.read(name)
    except StorageUnreachable:
        raise  # not "absent": the endpoint is gone, and so is this command
    except (FileNotFoundError, SmspaceError):
        return None
    try:
        with ShardReader.from_bytes(data, f"{folder.url}/{name}") as reader:
            if part == REGULAR:
                m, _ = reader.regular_sampling()
                return PartRecord.of(part, data, len(m), m.shape[1])
            if reader.metadata().get("config_hash") != cfg.config_hash:
                return None
            blocks = list(reader.blocks())
            stats = reader.stats()
    except (SmspaceError, ValueError):
        return None
    lo, hi = cfg.shard_range(part)
    if not blocks or sum(len(b.transitions) for b in blocks) != hi - lo:
        return None
    return _shard_record(part, data, blocks, stats)


def made_with(setup: str) -> dict[str, str]:
    """The versions that shaped a part's bytes in this process: the libraries, and the setup's own
    (SAPIEN, the Vulkan driver and device for the arm)."""
    return software_versions() | get_setup(setup).provenance()


def preflight(setup: str, world_seed: int | None = None) -> None:
    """The setup's own check (Vulkan for the arm), where the parts will be drawn; then its world
    `world_seed` is built and held to the contract on a probe batch (datagen/setups/contract.py)."""
    spec = get_setup(setup)
    with plugins.guarded(setup_plugin(setup), "in its preflight()"):
        spec.preflight()
    if world_seed is not None:
        check_world(spec, world_for(setup, world_seed), world_seed)
