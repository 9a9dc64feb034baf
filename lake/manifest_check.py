"""Every field of a manifest checked before anything trusts it: a hostile or hand-edited manifest
is named in one line instead of crashing a reader, and can name no file outside its folder."""

from __future__ import annotations

import math
import re
from typing import Any

from smspace.lake.manifest import MAX_FILE_BYTES, MAX_REGULAR, REGULAR_FILE, SEED_MAX, SHARD_FILE, GenConfig, shard_name
from smspace.lake.transitions import MODES

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
    if "md5" in entry and not _hex(entry["md5"], 32):  # recorded since 0.2; older manifests lack it
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
