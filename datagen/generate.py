"""Generate datasets into the lake: plan, write missing shards (in parallel), finalise.

Shard i is a pure function of (config, i): its random stream comes from
SeedSequence(world_seed, spawn_key=(1, mode, i)), so the bytes do not depend on the worker count
or on which shards an interrupted run had already written.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import signal
import sys
from collections.abc import Iterable
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

import schemas
from common.cli import die_with_parent
from common.errors import SmspaceError
from common.locks import hold_lock
from datagen.setups import MODES, World, draw_transitions, get_setup
from lake.atomic import remove_partials, sha256_file, write_atomic
from lake.catalog import check_lake, rebuild_catalog
from lake.manifest import (
    GENERATION,
    MANIFEST,
    MAX_SHARD_SIZE,
    REGULAR_FILE,
    GenConfig,
    Manifest,
    load_manifest,
    shard_name,
)
from lake.manifest_check import dataset_file
from lake.shards import Block, ShardReader, write_regular_sampling, write_shard

LOCKS = ".locks"  # lake/.locks/<dataset id>.lock: held while that dataset is being generated
_WORLDS: dict[tuple[str, int], World] = {}


def world_for(setup: str, seed: int) -> World:
    """One world per (setup, seed) per process: building the SAPIEN room is not free."""
    key = (setup, seed)
    if key not in _WORLDS:
        _WORLDS[key] = get_setup(setup).build(seed)
    return _WORLDS[key]


def shard_rng(cfg: GenConfig, i: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(cfg.world_seed, spawn_key=(1, MODES.index(cfg.mode), i)))


def _stats(blocks: list[Block]) -> dict[str, list[float]]:
    m = np.concatenate([b.transitions.m_t for b in blocks])
    s = np.concatenate([b.transitions.s_t.reshape(len(b.transitions), -1) for b in blocks])
    return {
        "m_min": m.min(0).astype(float).tolist(),
        "m_max": m.max(0).astype(float).tolist(),
        "s_min": s.min(0).astype(float).tolist(),
        "s_max": s.max(0).astype(float).tolist(),
    }


def write_one_shard(cfg: GenConfig, folder: Path, i: int) -> int:
    world = world_for(cfg.setup, cfg.world_seed)
    rng = shard_rng(cfg, i)
    lo, hi = cfg.shard_range(i)
    blocks = [
        Block(start, draw_transitions(world, cfg.mode, rng, min(cfg.batch_size, hi - start)))
        for start in range(lo, hi, cfg.batch_size)
    ]
    metadata = {
        "dataset_id": cfg.dataset_id,
        "shard_index": str(i),
        "first_index": str(lo),
        "transitions": str(hi - lo),
        "config_hash": cfg.config_hash,
        "stats": json.dumps(_stats(blocks)),
    }
    write_shard(folder / shard_name(i), blocks, metadata)
    return hi - lo


def _shard_is_good(path: Path, cfg: GenConfig, i: int) -> bool:
    """Keep a shard found under its final name only if it belongs to cfg and reads back whole: every
    chunk CRC checked and every batch decoded, so a shard damaged after it was written is redone."""
    if not _regular(path):
        return False
    lo, hi = cfg.shard_range(i)
    try:
        with ShardReader(path) as reader:
            if reader.metadata().get("config_hash") != cfg.config_hash:
                return False
            return sum(len(b.transitions) for b in reader.blocks()) == hi - lo
    except SmspaceError:
        return False


def _clear_dataset(folder: Path) -> None:
    for pattern in (MANIFEST, GENERATION, REGULAR_FILE, "shard-*.mcap"):
        for p in folder.glob(pattern):
            p.unlink()
    remove_partials(folder)


def _recorded_hash(folder: Path) -> str | None:
    for name in (MANIFEST, GENERATION):
        path = folder / name
        if path.exists():
            try:
                return json.loads(path.read_text())["config_hash"]
            except (json.JSONDecodeError, KeyError, UnicodeDecodeError):
                return "unreadable"
    return None


@dataclass
class Plan:
    cfg: GenConfig
    folder: Path
    todo: list[int]
    complete: bool


def plan_dataset(lake: Path, cfg: GenConfig, overwrite: bool) -> Plan:
    folder = lake / cfg.dataset_id
    if folder.exists() and not folder.is_dir():
        raise SmspaceError(f"{folder} exists and is not a folder")
    recorded = _recorded_hash(folder) if folder.exists() else None
    if recorded is not None and recorded != cfg.config_hash:
        if not overwrite:
            raise SmspaceError(
                f"dataset {cfg.dataset_id} in {lake} was generated with another config; "
                "pass --overwrite to replace it, or choose another --lake"
            )
        _clear_dataset(folder)
    elif recorded is not None and (folder / MANIFEST).exists():
        if _files_as_recorded(folder):
            return Plan(cfg, folder, [], complete=True)
        # a shard went missing or changed size: the dataset is incomplete again until repaired
        (folder / MANIFEST).unlink()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        remove_partials(folder)
    except OSError as e:
        raise SmspaceError(f"cannot write to {folder}: {e.strerror or e}") from e
    write_atomic(folder / GENERATION, json.dumps({"config": cfg.to_dict(), "config_hash": cfg.config_hash}).encode())
    todo = [i for i in range(cfg.n_shards) if not _shard_is_good(folder / shard_name(i), cfg, i)]
    return Plan(cfg, folder, todo, complete=False)


def _files_as_recorded(folder: Path) -> bool:
    """Cheap completeness check of a finished dataset: every file present with its recorded size."""
    manifest = load_manifest(folder)
    files = [*manifest.shards, manifest.regular_sampling]
    return all(_regular(folder / f["file"]) and (folder / f["file"]).stat().st_size == f["bytes"] for f in files)


def _regular(path: Path) -> bool:
    """A dataset file as readers accept it (docs/FORMAT.md): present, regular, not a link."""
    try:
        dataset_file(path.parent, path.name)
    except (FileNotFoundError, SmspaceError):
        return False
    return True


def _merge_stats(stats: list[dict[str, list[float]]]) -> dict[str, list[float]]:
    out = {}
    for key, fn in (("m_min", np.min), ("m_max", np.max), ("s_min", np.min), ("s_max", np.max)):
        out[key] = fn(np.array([s[key] for s in stats], np.float64), axis=0).tolist()
    return out


def finalize_dataset(plan: Plan) -> Manifest:
    cfg, folder = plan.cfg, plan.folder
    world = world_for(cfg.setup, cfg.world_seed)
    m_reg, p_reg = world.regular_sampling()
    write_regular_sampling(folder / REGULAR_FILE, m_reg, p_reg)
    shards, stats = [], []
    for i in range(cfg.n_shards):
        path = folder / shard_name(i)
        with ShardReader(path) as reader:
            stats.append(reader.stats())
        lo, hi = cfg.shard_range(i)
        shards.append(
            {
                "file": path.name,
                "first_index": lo,
                "transitions": hi - lo,
                "bytes": path.stat().st_size,
                "sha256": sha256_file(path),
            }
        )
    reg = folder / REGULAR_FILE
    manifest = Manifest(
        dataset_id=cfg.dataset_id,
        setup=cfg.setup,
        mode=cfg.mode,
        world_seed=cfg.world_seed,
        transitions=cfg.transitions,
        n_motor=world.n_motor,
        sensor_shape=list(world.sensor_shape),
        sensor_dtype=np.dtype(world.sensor_dtype).name,
        schema_version=schemas.SCHEMA_VERSION,
        config=cfg.to_dict(),
        config_hash=cfg.config_hash,
        shards=shards,
        normalisation=_merge_stats(stats),
        regular_sampling={
            "file": REGULAR_FILE,
            "count": len(m_reg),
            "bytes": reg.stat().st_size,
            "sha256": sha256_file(reg),
        },
        shift_bound=get_setup(cfg.setup).shift_bound,
    )
    manifest.write(folder)
    (folder / GENERATION).unlink(missing_ok=True)
    return manifest


def _run_tasks(tasks: list[tuple[GenConfig, Path, int]], workers: int) -> None:
    total = sum(cfg.shard_range(i)[1] - cfg.shard_range(i)[0] for cfg, _, i in tasks)
    with tqdm(total=total, unit="tr", unit_scale=True, disable=None, file=sys.stderr, desc="generating") as bar:
        if workers <= 1 or len(tasks) <= 1:
            for task in tasks:
                bar.update(write_one_shard(*task))
            return
        ctx = multiprocessing.get_context("spawn")  # SAPIEN hangs in forked children
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=die_with_parent, initargs=(signal.SIGKILL, os.getpid())
        ) as pool:
            try:
                futures = [pool.submit(write_one_shard, *task) for task in tasks]
                pending = set(futures)
                while pending:
                    done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                    for f in done:
                        bar.update(f.result())  # re-raises a worker's error here, after cleanup
            except BaseException:  # an error, Ctrl-C or SIGTERM: stop the workers now, not after their shards
                for process in list(pool._processes.values()):
                    process.kill()
                pool.shutdown(wait=True, cancel_futures=True)
                raise


MAX_TRANSITIONS = 2**40  # a dataset's transition indices are int64 log times; far beyond any disk


def _check_disk(lake: Path, configs: list[GenConfig], bytes_per_transition: int) -> None:
    """Refuse, before writing anything, a generation the disk cannot hold: the estimate counts only
    the shards not yet present (a resume needs little), with a margin for the files around them."""
    missing = sum(
        cfg.shard_range(i)[1] - cfg.shard_range(i)[0]
        for cfg in configs
        for i in range(cfg.n_shards)
        if not (lake / cfg.dataset_id / shard_name(i)).is_file()
    )
    needed = int(missing * bytes_per_transition * 1.1) + (len(configs) << 20)
    free = shutil.disk_usage(lake).free
    if needed > free:
        raise SmspaceError(
            f"the disk of {lake} has {free / 2**20:.0f} MiB free; this generation needs about {needed / 2**20:.0f} MiB"
        )


def generate(
    lake: Path,
    setup: str,
    modes: Iterable[str],
    world_seeds: Iterable[int],
    transitions: int,
    shard_size: int,
    workers: int = 1,
    overwrite: bool = False,
) -> list[tuple[Manifest, bool]]:
    """Generate (or complete) every (world, mode) dataset; returns (manifest, newly_written)."""
    if transitions <= 0:
        raise SmspaceError(f"--transitions must be positive, got {transitions}")
    if shard_size <= 0:
        raise SmspaceError(f"--shard-size must be positive, got {shard_size}")
    if shard_size > MAX_SHARD_SIZE:
        raise SmspaceError(f"--shard-size {shard_size} is more than a worker holds in memory ({MAX_SHARD_SIZE})")
    if transitions > MAX_TRANSITIONS:
        raise SmspaceError(f"--transitions {transitions} is more than a dataset may hold ({MAX_TRANSITIONS})")
    spec = get_setup(setup)
    spec.preflight()
    lake = check_lake(lake)
    configs = [GenConfig(setup, mode, seed, transitions, shard_size) for seed in world_seeds for mode in modes]
    _check_disk(lake, configs, spec.bytes_per_transition)
    # one generator per dataset: a second command on the same dataset waits, then finds it done
    locks = [
        hold_lock(lake / LOCKS / f"{cfg.dataset_id}.lock", f"another smgen is generating {cfg.dataset_id}", wait=True)
        for cfg in sorted(configs, key=lambda c: c.dataset_id)
    ]
    try:
        return _generate(lake, configs, workers, overwrite)
    finally:
        for lock in locks:
            lock.release()


def _generate(lake: Path, configs: list[GenConfig], workers: int, overwrite: bool) -> list[tuple[Manifest, bool]]:
    plans = [plan_dataset(lake, cfg, overwrite) for cfg in configs]
    _run_tasks([(p.cfg, p.folder, i) for p in plans for i in p.todo], workers)
    results = []
    for plan in plans:
        if plan.complete:
            results.append((load_manifest(plan.folder), False))
        else:
            results.append((finalize_dataset(plan), True))
    rebuild_catalog(lake)
    return results
