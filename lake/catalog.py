"""The lake-level catalog: one Parquet row per complete dataset, derived from the manifests.

The manifests are the truth; `catalog.parquet` is a cache of them that records which manifest
versions it was built from (ETags on S3, size and mtime locally). A reader lists the manifests
(one LIST request), and rebuilds the cache when the versions differ. So writers need no lock and
no compare-and-swap: a catalog overwritten by a concurrent generator is merely stale, and the
next reader notices and repairs it (docs/FORMAT.md, "Commit protocol")."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa

from smspace.common.cli import display_name
from smspace.common.errors import SmspaceError
from smspace.lake import parquet
from smspace.lake.manifest import MANIFEST, Manifest, load_manifest
from smspace.lake.store import StorageUnreachable, Store, open_store

CATALOG = "catalog.parquet"
SOURCES_KEY = b"smspace.manifests"  # Parquet metadata: {"versions": {id: manifest version}, "broken": [id…]}

CATALOG_SCHEMA = pa.schema(
    [
        ("id", pa.string()),
        ("setup", pa.string()),
        ("mode", pa.string()),
        ("world_seed", pa.int64()),
        ("transitions", pa.int64()),
        ("shards", pa.int32()),
        ("bytes", pa.int64()),
        ("n_motor", pa.int32()),
        ("sensor_shape", pa.list_(pa.int32())),
        ("schema_version", pa.int32()),
        ("config_hash", pa.string()),
    ]
)


def check_lake(lake: Path | str | Store) -> Store:
    """The lake, which must be a folder or not exist yet (checks that run before any write): a file
    there is a user error."""
    store = open_store(lake)
    if store.is_file():
        raise SmspaceError(f"lake path {store} is a file, not a folder")
    return store


def make_lake(lake: Store) -> Store:
    """Create a checked lake's folder if missing: the first write of a command that writes one."""
    try:
        lake.make()
    except SmspaceError as e:
        raise SmspaceError(f"cannot create lake folder {lake}: {e}") from None
    return lake


def manifest_versions(lake: Store) -> dict[str, str]:
    """{dataset id: version of its manifest}: one listing of the lake."""
    return {path.split("/", 1)[0]: tag for path, tag in lake.fingerprints(f"*/{MANIFEST}").items()}


def scan_manifests(lake: Path | str | Store) -> tuple[list[Manifest], list[str]]:
    """The sound manifests of a lake, and one line per dataset folder whose manifest is not."""
    store = open_store(lake)
    manifests, broken, _ = _scan(store, sorted(manifest_versions(store)))
    return manifests, [f"{display_name(i)}: {why}" for i, why in broken.items()]


def _scan(lake: Store, ids: list[str]) -> tuple[list[Manifest], dict[str, str], set[str]]:
    """(sound manifests, {id: why broken}, ids whose manifest was gone when read)."""
    manifests, broken, gone = [], {}, set()
    for dataset_id in ids:
        folder = lake.child(dataset_id)
        try:
            data = folder.read(MANIFEST)
        except FileNotFoundError:  # deleted since the listing (a repair under way): not known either way
            gone.add(dataset_id)
            continue
        except StorageUnreachable:
            raise
        except SmspaceError as e:
            broken[dataset_id] = str(e)
            continue
        try:
            manifests.append(load_manifest(folder, data))
        except SmspaceError as e:
            broken[dataset_id] = str(e)
    return manifests, broken, gone


def _rows(manifests: list[Manifest]) -> pa.Table:
    rows = [
        {
            "id": m.dataset_id,
            "setup": m.setup,
            "mode": m.mode,
            "world_seed": m.world_seed,
            "transitions": m.transitions,
            "shards": len(m.shards),
            "bytes": m.total_bytes,
            "n_motor": m.n_motor,
            "sensor_shape": m.sensor_shape,
            "schema_version": m.schema_version,
            "config_hash": m.config_hash,
        }
        for m in manifests
    ]
    return pa.Table.from_pylist(rows, schema=CATALOG_SCHEMA)


def rebuild_catalog(lake: Path | str | Store, versions: dict[str, str] | None = None) -> pa.Table:
    """The catalog anew from the manifests; a broken dataset is left out, never fatal.

    It records the manifest version each row was read from, and which datasets were broken: a
    dataset whose manifest was gone when read is recorded neither way, so the next reader finds
    the cache stale and reads it again (a repair that re-commits identical bytes keeps its ETag)."""
    lake = open_store(lake)
    versions = manifest_versions(lake) if versions is None else versions
    manifests, broken, gone = _scan(lake, sorted(versions))
    table = _rows(manifests)
    sources = {"versions": {k: v for k, v in versions.items() if k not in gone}, "broken": sorted(broken)}
    metadata = {SOURCES_KEY: json.dumps(sources, sort_keys=True).encode()}
    lake.put(CATALOG, parquet.table_bytes(table.replace_schema_metadata(metadata)))
    return table.replace_schema_metadata(None)


def _cache_holds(table: pa.Table, sources: dict, versions: dict[str, str]) -> bool:
    """Whether a cached table is exactly what the manifests listed now would give: the same
    versions, and one row for each of them that is not broken (no more, no fewer)."""
    if not (isinstance(sources, dict) and sources.get("versions") == versions and table.schema.equals(CATALOG_SCHEMA)):
        return False
    listed = set(versions) - set(sources.get("broken") or [])
    ids = table.column("id").to_pylist()
    return len(ids) == len(set(ids)) and set(ids) == listed


def read_catalog(lake: Path | str | Store, versions: dict[str, str] | None = None) -> pa.Table:
    """The catalog, checked against one listing of the manifests (`versions`, when the caller has
    just made it); rebuilt when stale or unreadable. A lake that does not exist yet is empty."""
    lake = open_store(lake)
    if not lake.is_folder():
        return CATALOG_SCHEMA.empty_table()
    versions = manifest_versions(lake) if versions is None else versions
    try:
        table = parquet.read_table(lake.read(CATALOG))  # lake/parquet.py: no abort at exit
        sources = json.loads((table.schema.metadata or {}).get(SOURCES_KEY, b"null"))
        table = table.replace_schema_metadata(None)
        if _cache_holds(table, sources, versions):
            return table
    except StorageUnreachable:
        raise
    except (OSError, pa.ArrowException, SmspaceError, ValueError):
        pass  # missing, unreadable or of an older layout: derive it again
    try:
        return rebuild_catalog(lake, versions)
    except StorageUnreachable:
        raise
    except SmspaceError:  # a lake we may not write: list it all the same
        return _rows(_scan(lake, sorted(versions))[0])
