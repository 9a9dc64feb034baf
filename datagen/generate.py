"""Generate datasets into the lake: plan, write the missing parts (anywhere), commit.

The lake may be a local folder or object storage; the protocol is the same (docs/FORMAT.md,
"Commit protocol"): every part goes whole to its final name, and once all are present and
valid the manifest is created, create-only. A dataset without a manifest is invisible to
`ls` and to every reader, so a killed generation leaves nothing that looks complete, and
re-running it completes it byte-identically. With --rank/--world-size a command writes only
its share of the parts and leaves the commit to `smgen finalize`.
"""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from smspace import schemas
from smspace.common import plugins
from smspace.common.errors import SmspaceError, one_line
from smspace.common.main_guard import refuse_unguarded
from smspace.datagen.executors import ExecutorOptions, open_part_writers
from smspace.datagen.parts import REGULAR, PartRecord, part_file, parts_of, verify_part
from smspace.datagen.setups import get_setup, setup_plugin
from smspace.lake.bounds import SHARD_SIZE, TRANSITIONS
from smspace.lake.catalog import check_lake, make_lake, rebuild_catalog
from smspace.lake.exploration import Exploration
from smspace.lake.integrity import file_problem
from smspace.lake.manifest import (
    GENERATION,
    MANIFEST,
    REGULAR_FILE,
    GenConfig,
    Manifest,
    load_manifest,
    software_versions,
)
from smspace.lake.store import Store, exists, free_bytes, listing, remove_partials

LOCKS = ".locks"  # lake/.locks/<dataset id>.lock: held while that dataset is generated (local lakes)


@dataclass(frozen=True)
class Share:
    """Which parts this command writes: all of them, or those of one rank of a job array."""

    rank: int = 0
    world_size: int = 1

    def __post_init__(self) -> None:
        if self.world_size < 1 or not 0 <= self.rank < self.world_size:
            raise SmspaceError(f"--rank {self.rank} is not in 0 .. --world-size {self.world_size} - 1")

    @property
    def whole(self) -> bool:
        return self.world_size == 1

    def owns(self, part: int) -> bool:
        """Shard i belongs to rank i % W; the regular-sampling file to rank 0."""
        return (0 if part == REGULAR else part) % self.world_size == self.rank


@dataclass
class Plan:
    cfg: GenConfig
    folder: Store
    todo: list[int]
    found: dict[int, PartRecord]  # parts already stored and verified
    complete: bool


READ_ATTEMPTS = 3  # a record that does not parse is read again: a garbled or cut transfer is not a config


def _recorded(folder: Store) -> tuple[str, dict] | None:
    """(config hash, config) of the dataset's manifest or unfinished generation; None if neither.
    Only a record read whole and parsed is compared: one that does not parse is read again, and
    if it never does it is named as unreadable, never taken for another config (advice to pass
    --overwrite would delete a sound dataset after one garbled transfer)."""
    for name in (MANIFEST, GENERATION):
        problem = ""
        for _ in range(READ_ATTEMPTS):
            try:
                raw = json.loads(folder.read(name))
                return raw["config_hash"], raw["config"] if isinstance(raw.get("config"), dict) else {}
            except (FileNotFoundError, NotADirectoryError):
                break
            except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError) as e:
                problem = one_line(e, with_type=True)
        if problem:
            raise SmspaceError(
                f"{folder}/{name} could not be read whole in {READ_ATTEMPTS} attempts ({problem}); "
                "if the storage answers soundly, the file is damaged: `smgen validate` names it, and "
                "--overwrite draws the dataset again"
            )
    return None


def _what_changed(recorded: dict, cfg: GenConfig) -> str:
    """The config fields that differ, plugin fields by name ("plugin code_sha256 a -> b")."""
    now = cfg.to_dict()
    was_plugin, now_plugin = recorded.get("plugin") or {}, now.get("plugin") or {}
    parts = [f"plugin {plugins.changes(was_plugin, now_plugin)}"] if was_plugin != now_plugin else []
    rest = {k: v for k, v in recorded.items() if k != "plugin"}
    if {k: v for k, v in now.items() if k != "plugin"} != rest:
        parts.append(plugins.changes(rest, {k: v for k, v in now.items() if k != "plugin"}))
    return "; ".join(parts)


def _clear_dataset(folder: Store) -> None:
    for name in [MANIFEST, GENERATION, REGULAR_FILE, *listing(folder, "shard-*.mcap")]:
        folder.delete(name)
    remove_partials(folder)


def damaged_files(folder: Store) -> list[tuple[str, str]]:
    """(file, what is wrong) for every file of a finished dataset that is not the recorded one:
    missing, of another size, or of other bytes (lake/integrity.py)."""
    manifest = load_manifest(folder)
    entries = [*manifest.shards, manifest.regular_sampling]
    return [(entry["file"], problem) for entry in entries if (problem := file_problem(folder, entry))]


def plan_dataset(
    lake: Store,
    cfg: GenConfig,
    overwrite: bool,
    share: Share = Share(),
    notify: Callable[[str], None] = lambda line: None,
) -> Plan:
    folder = lake.child(cfg.dataset_id)
    found = _recorded(folder)
    recorded = found[0] if found else None
    if recorded is not None and recorded != cfg.config_hash:
        if not overwrite:
            changed = _what_changed(found[1], cfg) if found[1] else ""
            raise SmspaceError(
                f"dataset {cfg.dataset_id} in {lake} was generated with another config"
                f"{f' ({changed})' if changed else ''}; pass --overwrite to replace it, or choose another --lake"
            )
        _clear_dataset(folder)
    elif recorded is not None and exists(folder, MANIFEST):
        damaged = damaged_files(folder)
        if not damaged:
            return Plan(cfg, folder, [], {}, complete=True)
        if not share.whole:  # ranks run side by side: none may take a committed dataset apart
            name, problem = damaged[0]
            raise SmspaceError(f"{folder}/{name}: {problem}; repair it with a plain `smgen generate` (no --rank)")
        for name, problem in damaged:  # the dataset is incomplete again until these are redrawn
            notify(f"{cfg.dataset_id}: {name}: {problem}; drawing it again")
            folder.delete(name)
        folder.delete(MANIFEST)
    folder.make()
    if share.whole:  # ranks of an array run side by side: none may delete another's temporary files
        remove_partials(folder)
    folder.put(GENERATION, json.dumps({"config": cfg.to_dict(), "config_hash": cfg.config_hash}).encode())
    mine = [p for p in parts_of(cfg) if share.owns(p)]
    found = {p: r for p in mine if (r := verify_part(cfg, folder, p)) is not None}
    return Plan(cfg, folder, [p for p in mine if p not in found], found, complete=False)


def _merge_stats(stats: list[dict[str, list[float]]]) -> dict[str, list[float]]:
    out = {}
    for key, fn in (("m_min", np.min), ("m_max", np.max), ("s_min", np.min), ("s_max", np.max)):
        out[key] = fn(np.array([s[key] for s in stats], np.float64), axis=0).tolist()
    return out


def build_manifest(cfg: GenConfig, records: dict[int, PartRecord]) -> Manifest:
    """The manifest of a dataset whose every part is stored and verified."""
    shards = [records[i] for i in range(cfg.n_shards)]
    reg = records[REGULAR]
    first = shards[0]
    if any(
        (r.n_motor, r.sensor_shape, r.sensor_dtype) != (first.n_motor, first.sensor_shape, first.sensor_dtype)
        for r in shards
    ):
        raise SmspaceError(f"dataset {cfg.dataset_id}: shards of different shapes; regenerate it with --overwrite")
    return Manifest(
        dataset_id=cfg.dataset_id,
        setup=cfg.setup,
        mode=cfg.mode,
        world_seed=cfg.world_seed,
        transitions=cfg.transitions,
        n_motor=first.n_motor,
        sensor_shape=list(first.sensor_shape),
        sensor_dtype=first.sensor_dtype,
        schema_version=schemas.WALKS_VERSION if cfg.explored.walks else schemas.TRANSITIONS_VERSION,
        config=cfg.to_dict(),
        config_hash=cfg.config_hash,
        shards=[
            {"file": r.file, "first_index": cfg.shard_range(r.part)[0], "transitions": r.count} | r.entry()
            for r in shards
        ],
        normalisation=_merge_stats([r.stats for r in shards]),
        regular_sampling={"file": REGULAR_FILE, "count": reg.count} | reg.entry(),
        shift_bound=get_setup(cfg.setup).shift_bound,
        network={"encoder_layers": list(get_setup(cfg.setup).encoder_layers)},
        software=_made_with([records[i] for i in parts_of(cfg)]),
    )


def _made_with(records: list[PartRecord]) -> dict[str, str]:
    """The software of the parts written now (a value that differs between them lists every one);
    parts found already stored were written by an earlier command, which is said, not guessed."""
    known = [r.software for r in records if r.software is not None]
    if not known:
        note = "every part was found stored, written by an earlier command: these are the committing command's"
        return software_versions() | {"note": note}
    keys = dict.fromkeys(k for s in known for k in s)
    merged = {key: " | ".join(sorted({s.get(key, "unknown") for s in known})) for key in keys}
    if len(known) < len(records):
        merged["note"] = f"{len(records) - len(known)} of {len(records)} parts were written by an earlier command"
    return merged


def commit_dataset(folder: Store, cfg: GenConfig, records: dict[int, PartRecord]) -> tuple[Manifest, bool]:
    """Create the manifest (the commit point); (manifest, True) if this call committed it. When
    another generator committed first, its manifest stands if it records the same content."""
    manifest = build_manifest(cfg, records)
    try:
        manifest.commit(folder)  # a retry of our own commit whose answer was lost counts as ours (lake/store.py)
    except FileExistsError:
        existing = load_manifest(folder)
        if (existing.config_hash, existing.shards_digest) != (manifest.config_hash, manifest.shards_digest):
            raise SmspaceError(
                f"dataset {cfg.dataset_id} was committed meanwhile with other content; run validate on it"
            ) from None
        folder.delete(GENERATION)  # the generation is done, whoever committed it
        return existing, False
    folder.delete(GENERATION)
    return manifest, True


def _check_request(transitions: int, shard_size: int) -> None:
    TRANSITIONS.coerce(transitions, "--transitions")
    SHARD_SIZE.coerce(shard_size, "--shard-size")


def default_sizes(setup: str, walk: Exploration, transitions: int | None, shard_size: int | None) -> tuple[int, int]:
    """(transitions, shard size): those given, else the setup's defaults, which walks round down to
    whole episodes (a size given that is not is refused later, in one line)."""
    spec = get_setup(setup)
    unit = walk.length if walk.walks else 1
    n = spec.default_transitions // unit * unit if transitions is None else transitions
    shard = max(unit, spec.default_shard_size // unit * unit) if shard_size is None else shard_size
    return n, shard


def probe_walk(setup: str, world_seed: int, walk: Exploration) -> None:
    """Refuse walks before anything is written if the setup's world cannot draw a short one that
    keeps the setup contract (a plugin's `walk_motors` answers to it as its other methods do)."""
    from smspace.datagen.parts import world_for
    from smspace.datagen.setups import setup_label
    from smspace.datagen.setups.contract import check_block, declared
    from smspace.datagen.walks import draw_walks

    spec, world = get_setup(setup), world_for(setup, world_seed)
    if not callable(getattr(world, "walk_motors", None)):
        raise SmspaceError(
            f"setup {setup_label(setup)} cannot walk: its world, {type(world).__name__}, has no "
            "walk_motors(rng, episodes, length, step)"
        )
    where = f"{setup_label(setup)}, walks of world {world_seed}"
    with plugins.guarded(setup_plugin(setup), f"drawing {where}"):
        walks = draw_walks(world, "MM", np.random.default_rng(0), 1, min(walk.length, 4), walk.step)
    check_block(walks.transitions, declared(spec, world, where), where)


def check_disk(
    lake: Store | str, setup: str, modes: Iterable[str], world_seeds: Iterable[int], transitions: int,
    exploration: Exploration | None = None,
) -> None:  # fmt: skip
    """What `generate` would refuse for want of disk, refused by a caller that writes before it
    (a study records itself first)."""
    spec, walk = get_setup(setup), exploration or Exploration()
    shard = default_sizes(setup, walk, transitions, None)[1]
    configs = [
        GenConfig(setup, mode, seed, transitions, shard, exploration=walk.record())
        for seed in world_seeds
        for mode in modes
    ]
    _check_disk(check_lake(lake), configs, spec.bytes_per_transition, Share())


def _check_disk(lake: Store, configs: list[GenConfig], bytes_per_transition: int, share: Share) -> None:
    """Refuse, before writing anything, a generation the disk cannot hold: the estimate counts only
    the shards not yet present (a resume needs little), with a margin for the files around them.
    One listing per dataset, never a request per shard: a dataset may have millions. Object storage
    has no such limit to check."""
    free = free_bytes(lake)
    if free is None:
        return
    missing = sum(_missing_transitions(cfg, lake.child(cfg.dataset_id), share) for cfg in configs)
    needed = int(missing * bytes_per_transition * 1.1) + (len(configs) << 20)
    if needed > free:
        raise SmspaceError(
            f"the disk of {lake} has {free / 2**20:.0f} MiB free; this generation needs about {needed / 2**20:.0f} MiB"
        )


def _missing_transitions(cfg: GenConfig, folder: Store, share: Share) -> int:
    """Transitions of the shards `share` owns that are not stored yet, counted without a loop over
    the shards: every shard holds shard_size transitions but the last."""
    owned, last = range(share.rank, cfg.n_shards, share.world_size), cfg.n_shards - 1
    short = cfg.shard_size - _shard_length(cfg, last) if last in owned else 0
    present = {int(m[1]) for name in folder.fingerprints("shard-*.mcap") if (m := SHARD_FILE.fullmatch(name))}
    return len(owned) * cfg.shard_size - short - sum(_shard_length(cfg, i) for i in present if i in owned)


SHARD_FILE = re.compile(r"shard-(\d{5,})\.mcap")


def _shard_length(cfg: GenConfig, i: int) -> int:
    lo, hi = cfg.shard_range(i)
    return hi - lo


def generate(
    lake: Store | str,
    setup: str,
    modes: Iterable[str],
    world_seeds: Iterable[int],
    transitions: int,
    shard_size: int,
    workers: int = 1,
    overwrite: bool = False,
    executor: str = "local",
    share: Share = Share(),
    options: ExecutorOptions | None = None,
    notify: Callable[[str], None] = lambda line: None,
    exploration: Exploration | None = None,
) -> list[tuple[Manifest | None, bool]]:
    """Generate (or complete, or repair) every (world, mode) dataset; returns (manifest, newly
    committed) per dataset, the manifest None where a rank of an array left the commit to `finalize`.
    `notify`: where a repair is said; `exploration`: independent transitions or walks."""
    _check_request(transitions, shard_size)
    exploration = exploration or Exploration()
    if problem := exploration.problem(transitions, shard_size):
        raise SmspaceError(problem)
    if exploration.walks and world_seeds:
        probe_walk(setup, next(iter(world_seeds)), exploration)
    if overwrite and not share.whole:
        raise SmspaceError("--overwrite cannot be combined with --world-size: ranks would delete each other's parts")
    spec, plugin = get_setup(setup), setup_plugin(setup)
    record = plugin.record() if plugin is not None else None  # a changed plugin is a changed config
    world_seeds = list(world_seeds)
    options = options or ExecutorOptions(workers=workers)
    if executor == "local" and options.workers > 1:
        refuse_unguarded(f"smspace.generate(workers={options.workers})")
    with contextlib.ExitStack() as held:
        probe = world_seeds[0] if world_seeds else None  # the setup contract on a probe batch, before any write
        run_parts = held.enter_context(open_part_writers(executor, setup, options, probe))
        lake = check_lake(lake)
        sizes = transitions, shard_size
        walked = exploration.record()
        configs = [
            GenConfig(setup, mode, seed, *sizes, plugin=record, exploration=walked)
            for seed in world_seeds
            for mode in modes
        ]
        _check_disk(lake, configs, spec.bytes_per_transition, share)
        make_lake(lake)
        if share.whole:  # one generator per dataset: a second command waits, then finds it done
            for cfg in sorted(configs, key=lambda c: c.dataset_id):
                busy = f"another smgen is generating {cfg.dataset_id}"
                held.enter_context(lake.lock(f"{LOCKS}/{cfg.dataset_id}.lock", busy, wait=True))
        plans = [plan_dataset(lake, cfg, overwrite, share, notify) for cfg in configs]
        tasks = [(p.cfg, p.folder, part) for p in plans for part in p.todo]
        by_id = {p.cfg.dataset_id: p for p in plans}
        for (cfg, _, _), record in run_parts(tasks):
            by_id[cfg.dataset_id].found[record.part] = record
        results: list[tuple[Manifest | None, bool]] = []
        for plan in plans:
            if plan.complete:
                results.append((load_manifest(plan.folder), False))
            elif share.whole:
                results.append(commit_dataset(plan.folder, plan.cfg, plan.found))
            else:
                results.append((None, False))
    if share.whole:
        rebuild_catalog(lake)
    return results


def finalize(lake: Store | str, folders: list[Store]) -> list[tuple[Manifest, bool]]:
    """Commit datasets whose parts were written by the ranks of an array: every part must be
    present and valid (each is read whole), else nothing is committed and the first gap is named."""
    lake = make_lake(check_lake(lake))
    ready = []
    for folder in folders:
        if exists(folder, MANIFEST):
            ready.append((folder, None, None))
            continue
        try:
            raw = json.loads(folder.read(GENERATION))
            cfg = GenConfig.from_record(raw["config"], f"{folder}/{GENERATION}")
        except FileNotFoundError:
            if exists(folder, MANIFEST):  # another finalize committed it (and removed the record) meanwhile
                ready.append((folder, None, None))
                continue
            raise SmspaceError(f"{folder} has no generation to finalize (no {GENERATION})") from None
        except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError) as e:
            raise SmspaceError(f"{folder}/{GENERATION} is unreadable ({type(e).__name__}: {e})") from None
        records = {}
        for part in parts_of(cfg):
            record = verify_part(cfg, folder, part)
            if record is None:
                what = (
                    "not written yet (its rank is still running, or failed)"
                    if not exists(folder, part_file(part))
                    else "invalid (corrupt, or of another config)"
                )
                raise SmspaceError(f"cannot finalize {cfg.dataset_id}: {part_file(part)} is {what}; re-run its rank")
            records[part] = record
        ready.append((folder, cfg, records))
    results = []
    for folder, cfg, records in ready:
        results.append((load_manifest(folder), False) if cfg is None else commit_dataset(folder, cfg, records))
    rebuild_catalog(lake)
    return results
