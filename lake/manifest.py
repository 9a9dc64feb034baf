"""The per-dataset manifest: what was generated, how, and how to check and normalise it; and the
check of every field of a manifest read back (nothing is trusted before it passes)."""

from __future__ import annotations

import hashlib
import json
import math
import platform
import re
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from smspace import schemas
from smspace.common.errors import DatasetCorrupt, SmspaceError
from smspace.lake.exploration import Exploration
from smspace.lake.integrity import read_verified
from smspace.lake.store import Store, exists, open_store
from smspace.lake.transitions import MODES

MANIFEST = "manifest.json"
GENERATION = "generation.json"  # present only while a generation is unfinished
REGULAR_FILE = "regular.mcap"
BATCH_SIZE = 1024
SEED_MAX = 2**63 - 1  # a world seed is an int64 in the catalog
MAX_WORLDS = 100_000  # worlds in one command: the plan of every dataset is held in memory
MAX_SHARD_SIZE = 1 << 18  # transitions per shard: a worker holds one shard in memory (arm: ~0.5 GB)
# Bounds on every number a manifest or generation.json holds, so that a hostile or mistyped record is
# named in one line instead of overflowing a sum or sizing an allocation.
MAX_TRANSITIONS = 2**40  # a dataset's transition indices are int64 log times; far beyond any disk
MAX_SHARDS = 1 << 20
MAX_BATCH_SIZE = 1 << 16  # transitions per batch message
MAX_FILE_BYTES = 1 << 40  # one file; so that sums over a lake stay far inside int64
MAX_REGULAR = 1 << 26  # regular-sampling states (15625 for six motors)
SHARD_FILE = re.compile(r"shard-\d{5}\.mcap")


def dataset_id(setup: str, world_seed: int, mode: str) -> str:
    """The lake's name for one (setup, world, mode) dataset: what generation writes and training finds."""
    return f"{setup}-seed{world_seed}-{mode}"


@dataclass(frozen=True)
class GenConfig:
    """Everything a dataset's bytes depend on (the worker count is deliberately absent)."""

    setup: str
    mode: str
    world_seed: int
    transitions: int
    shard_size: int
    batch_size: int = BATCH_SIZE
    # a plugin setup's code: {entry_point, distribution, version, code_sha256} (None: smspace's own
    # setup, and then absent from the record, so that those hashes are what they always were)
    plugin: dict[str, str] | None = None
    # how the agent explored (lake/exploration.py): None for independent transitions, and then
    # absent from the record, as `plugin` is
    exploration: dict[str, Any] | None = None

    @property
    def explored(self) -> Exploration:
        return Exploration.from_record(self.exploration)

    @property
    def dataset_id(self) -> str:
        return dataset_id(self.setup, self.world_seed, self.mode) + self.explored.suffix

    @property
    def n_shards(self) -> int:
        return -(-self.transitions // self.shard_size)

    def shard_range(self, i: int) -> tuple[int, int]:
        lo = i * self.shard_size
        return lo, min(lo + self.shard_size, self.transitions)

    def to_dict(self) -> dict[str, Any]:
        record = asdict(self)
        for optional in ("plugin", "exploration"):
            if record[optional] is None:
                del record[optional]
        return record

    def problem(self) -> str | None:
        """What makes this config impossible to hold or to trust, or None."""
        ints = ("world_seed", "transitions", "shard_size", "batch_size")
        if not all(isinstance(getattr(self, k), int) and not isinstance(getattr(self, k), bool) for k in ints):
            return "config counts are not integers"
        if not (isinstance(self.setup, str) and isinstance(self.mode, str) and 0 <= self.world_seed <= SEED_MAX):
            return "config names no valid setup, mode or seed"
        plugin = self.plugin
        if plugin is not None and not (
            isinstance(plugin, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in plugin.items())
        ):
            return "config plugin is not a record of strings"
        try:
            walks = self.explored
        except ValueError as e:
            return f"config {e}"
        bounds = (
            ("transitions", 1, MAX_TRANSITIONS),
            ("shard_size", 1, MAX_SHARD_SIZE),
            ("batch_size", 1, MAX_BATCH_SIZE),
        )
        for name, low, high in bounds:
            if not low <= getattr(self, name) <= high:
                return f"config {name} {getattr(self, name)} is outside {low}..{high}"
        if self.n_shards > MAX_SHARDS:
            return f"config makes {self.n_shards} shards, more than {MAX_SHARDS}"
        return walks.problem(self.transitions, self.shard_size)

    @classmethod
    def from_record(cls, raw: Any, where: str) -> GenConfig:
        """A config read from a manifest or generation.json: every field checked, one line if not."""
        try:
            cfg = cls(**raw)
        except TypeError:
            raise DatasetCorrupt(f"{where}: config has other fields than a generation config") from None
        problem = cfg.problem()
        if problem:
            raise DatasetCorrupt(f"{where}: {problem}")
        return cfg

    @property
    def config_hash(self) -> str:
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


def shard_name(i: int) -> str:
    return f"shard-{i:05d}.mcap"


def software_versions() -> dict[str, str]:
    names = ["smspace", "numpy", "mcap", "mcap-protobuf-support", "protobuf", "zstandard"]
    versions = {"python": platform.python_version()}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "unknown"
    return versions


@dataclass
class Manifest:
    dataset_id: str
    setup: str
    mode: str
    world_seed: int
    transitions: int
    n_motor: int
    sensor_shape: list[int]
    sensor_dtype: str
    schema_version: int
    config: dict[str, Any]
    config_hash: str
    shards: list[dict[str, Any]]  # file, first_index, transitions, bytes, sha256
    normalisation: dict[str, list[float]]  # m_min, m_max (over m_t), s_min, s_max (over s_t)
    regular_sampling: dict[str, Any]  # file, count, bytes, sha256
    # |shift component| ≤ shift_bound in MEM and MME (the MM shift is one fixed value); recorded so
    # that validate needs no knowledge of the setups. None in manifests written before it was recorded.
    shift_bound: float | None = None
    # the network the setup suggests for its agent: {"encoder_layers": [...]}, so that training on
    # the dataset needs no knowledge of the setups (None in manifests written before it was recorded)
    network: dict[str, Any] | None = None
    software: dict[str, str] = field(default_factory=software_versions)

    @property
    def shards_digest(self) -> str:
        """One hash of the whole dataset's content, from the shards' recorded sha256s."""
        return hashlib.sha256("".join(s["sha256"] for s in self.shards).encode()).hexdigest()

    @property
    def total_bytes(self) -> int:
        return sum(s["bytes"] for s in self.shards) + self.regular_sampling["bytes"]

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    def commit(self, folder: Store) -> None:
        """The commit point of a generation: create-only, so of two generators one commits and the
        other gets FileExistsError (docs/FORMAT.md, "Commit protocol")."""
        folder.create(MANIFEST, self.to_json().encode())

    @property
    def exploration_words(self) -> str:
        """How the agent explored, as `smgen info` says it: "transitions" or the walk's terms."""
        walk = Exploration.from_record(self.config.get("exploration"))
        return f"walk: episodes of {walk.length} steps of {walk.step:g}" if walk.walks else "transitions"

    def summary(self) -> dict[str, Any]:
        """The short form shown by `smgen info --json`."""
        return {
            "id": self.dataset_id,
            "setup": self.setup,
            "mode": self.mode,
            "world_seed": self.world_seed,
            "transitions": self.transitions,
            "shards": len(self.shards),
            "bytes": self.total_bytes,
            "schema_version": self.schema_version,
            "exploration": self.exploration_words,
            "n_motor": self.n_motor,
            "sensor_shape": self.sensor_shape,
            "sensor_dtype": self.sensor_dtype,
            "regular_sampling_size": self.regular_sampling["count"],
            "config_hash": self.config_hash,
        }


def load_manifest(folder: Path | Store, data: bytes | None = None) -> Manifest:
    """The manifest of a dataset folder, every field checked (types, names, hashes, statistics);
    `data`: its bytes when the caller already fetched them (a lake listing)."""
    folder = open_store(folder)
    path = f"{folder.url}/{MANIFEST}"
    if data is not None and _json_problem(data) is None:
        raw = json.loads(data)
    else:  # read (again): bytes garbled on the way are a transfer's fault, not a corrupt manifest
        try:
            data, problem = read_verified(folder, MANIFEST, _json_problem)
        except (FileNotFoundError, NotADirectoryError):
            if exists(folder, GENERATION):
                incomplete = f"dataset {folder} is incomplete (its generation did not finish): re-run it"
                raise SmspaceError(incomplete) from None
            raise SmspaceError(f"{folder} is not a dataset (no {MANIFEST})") from None
        except DatasetCorrupt as e:
            raise DatasetCorrupt(f"corrupt manifest {path}: not a regular file") from e
        if problem is not None:
            raise DatasetCorrupt(f"corrupt manifest {path}: {problem}")
        raw = json.loads(data)
    if not isinstance(raw, dict):
        raise DatasetCorrupt(f"corrupt manifest {path}: not a JSON object")
    version = raw.get("schema_version")
    if isinstance(version, bool) or version not in schemas.READABLE:
        readable = ", ".join(map(str, schemas.READABLE))
        raise SmspaceError(f"dataset {folder} has schema version {version}; this smspace reads versions {readable}")
    problem = check_manifest(raw)
    if problem:
        raise DatasetCorrupt(f"corrupt manifest {path}: {problem}")
    config = raw.get("config")
    walks = isinstance(config, dict) and config.get("exploration") is not None
    if version != (schemas.WALKS_VERSION if walks else schemas.TRANSITIONS_VERSION):
        kind = "walks" if walks else "independent transitions"
        raise DatasetCorrupt(f"corrupt manifest {path}: schema version {version} for a dataset of {kind}")
    known = {f for f in Manifest.__dataclass_fields__}
    return Manifest(**{k: v for k, v in raw.items() if k in known})  # fields of later versions are ignored


def _json_problem(data: bytes) -> str | None:
    try:
        json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        return str(e)
    return None


# -- every field of a manifest, checked before anything trusts it: a hostile or hand-edited
# manifest is named in one line instead of crashing a reader, and can name no file outside its folder
DTYPES = ("float32", "uint8")
MAX_SENSOR = 1 << 24  # sensor components (768 for a 16x16 RGB camera)


def _int(v: Any, low: int = 0, high: int = SEED_MAX) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and low <= v <= high


def _floats(v: Any, n: int) -> bool:
    return (
        isinstance(v, list)
        and len(v) == n
        and all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    )


def _file_entry(entry: Any, names: re.Pattern | str) -> str | None:
    if not isinstance(entry, dict):
        return "a file entry is not an object"
    name = entry.get("file")
    ok = isinstance(name, str) and (names.fullmatch(name) if not isinstance(names, str) else name == names)
    if not ok:
        return f"file entry {name!r} is not a file name this format uses"
    if not (_int(entry.get("bytes"), 0, MAX_FILE_BYTES) and _hex(entry.get("sha256"), 64)):
        return f"{name}: bytes or sha256 missing or malformed"
    if "md5" in entry and not _hex(entry["md5"], 32):  # optional: manifests written before md5s lack it
        return f"{name}: md5 malformed"
    return None


def _hex(v: Any, length: int) -> bool:
    return isinstance(v, str) and len(v) == length and all(c in "0123456789abcdef" for c in v)


def check_manifest(raw: dict[str, Any]) -> str | None:
    """The first problem found, or None: the manifest is sound as a record (files are checked apart)."""
    problem = _check_identity(raw) or _check_shapes(raw) or _check_files(raw) or _check_normalisation(raw)
    return problem


def _check_identity(raw: dict[str, Any]) -> str | None:
    config = raw.get("config")
    if not isinstance(config, dict):
        return "config is not an object"
    try:
        gen = GenConfig(**config)
    except TypeError:
        return "config has other fields than a generation config"
    problem = gen.problem()
    if problem:
        return problem
    if gen.mode not in MODES:
        return "config names no valid setup, mode or seed"
    if raw.get("config_hash") != gen.config_hash:
        return "config_hash does not match config"
    expected = {"dataset_id": gen.dataset_id, "setup": gen.setup, "mode": gen.mode, "world_seed": gen.world_seed}
    expected["transitions"] = gen.transitions
    for key, value in expected.items():
        if raw.get(key) != value:
            return f"{key} {raw.get(key)!r} does not match its config ({value!r})"
    return None


def _check_shapes(raw: dict[str, Any]) -> str | None:
    if not _int(raw.get("n_motor"), 1, 4096):
        return "n_motor is not a positive integer"
    shape = raw.get("sensor_shape")
    if not (isinstance(shape, list) and 1 <= len(shape) <= 3 and all(_int(d, 1, 1 << 16) for d in shape)):
        return "sensor_shape is not a list of positive integers"
    if math.prod(shape) > MAX_SENSOR:
        return f"sensor_shape {shape} has more than {MAX_SENSOR} components"
    if raw.get("sensor_dtype") not in DTYPES:
        return f"sensor_dtype {raw.get('sensor_dtype')!r} is not one of {', '.join(DTYPES)}"
    network = raw.get("network")
    if network is not None:
        layers = network.get("encoder_layers") if isinstance(network, dict) else None
        if not (isinstance(layers, list) and len(layers) <= 32 and all(_int(w, 1, 1 << 16) for w in layers)):
            return "network encoder_layers is not a short list of positive integers"
    bound = raw.get("shift_bound")
    if bound is not None and not (isinstance(bound, int | float) and math.isfinite(bound) and bound >= 0):
        return "shift_bound is not a finite non-negative number"
    return None


def _check_files(raw: dict[str, Any]) -> str | None:
    shards = raw.get("shards")
    if not isinstance(shards, list) or not shards:
        return "shards is not a non-empty list"
    gen = GenConfig(**raw["config"])
    if len(shards) != gen.n_shards:
        return f"{len(shards)} shards listed, the config makes {gen.n_shards}"
    for i, shard in enumerate(shards):
        problem = _file_entry(shard, SHARD_FILE)
        if problem:
            return problem
        lo, hi = gen.shard_range(i)
        if (shard["file"], shard.get("first_index"), shard.get("transitions")) != (shard_name(i), lo, hi - lo):
            return f"shard entry {i} ({shard['file']}) does not match the config's shard {i}"
    reg = raw.get("regular_sampling")
    problem = _file_entry(reg, REGULAR_FILE)
    if problem:
        return problem
    if not _int(reg.get("count"), 1, MAX_REGULAR):
        return f"regular_sampling count is not an integer in 1..{MAX_REGULAR}"
    return None


def _check_normalisation(raw: dict[str, Any]) -> str | None:
    norm = raw.get("normalisation")
    if not isinstance(norm, dict):
        return "normalisation is not an object"
    n_sensor = math.prod(raw["sensor_shape"])
    for prefix, n in (("m", raw["n_motor"]), ("s", n_sensor)):
        lo, hi = norm.get(f"{prefix}_min"), norm.get(f"{prefix}_max")
        if not (_floats(lo, n) and _floats(hi, n)):
            return f"normalisation {prefix}_min/{prefix}_max are not {n} finite numbers each"
        if any(a > b for a, b in zip(lo, hi, strict=True)):
            return f"normalisation {prefix}_min exceeds {prefix}_max"
    return None
