"""The lake-level catalog: one Parquet row per complete dataset, derived from the manifests.

The manifests are the truth; `catalog.parquet` is a cache of them that records which manifest
versions it was built from (ETags on S3, size and mtime locally). A reader lists the manifests
(one LIST request), and rebuilds the cache when the versions differ. So writers need no lock and
no compare-and-swap: a catalog overwritten by a concurrent generator is merely stale, and the
next reader notices and repairs it (docs/FORMAT.md, "Commit protocol")."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from common.cli import display_name
from common.errors import SmspaceError
from lake.manifest import MANIFEST, Manifest, load_manifest
from lake.store import Store, open_store

CATALOG = "catalog.parquet"
SOURCES_KEY = b"smspace.manifests"  # Parquet metadata: {dataset id: manifest version}

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


def _store(lake: Path | str | Store) -> Store:
    return lake if isinstance(lake, Store) else open_store(lake)


def check_lake(lake: Path | str | Store) -> Store:
    """The lake must be a folder (created if missing); a file there is a user error."""
    store = _store(lake)
    if store.is_file():
        raise SmspaceError(f"lake path {store} is a file, not a folder")
    try:
        store.make()
    except SmspaceError as e:
        raise SmspaceError(f"cannot create lake folder {store}: {e}") from None
    return store


def manifest_versions(lake: Store) -> dict[str, str]:
    """{dataset id: version of its manifest}: one listing of the lake."""
    return {path.split("/", 1)[0]: tag for path, tag in lake.fingerprints(f"*/{MANIFEST}").items()}


def scan_manifests(lake: Path | str | Store, ids: list[str] | None = None) -> tuple[list[Manifest], list[str]]:
    """The sound manifests of a lake, and one line per dataset folder whose manifest is not."""
    lake = _store(lake)
    manifests, broken = [], []
    for dataset_id in sorted(manifest_versions(lake) if ids is None else ids):
        try:
            manifests.append(load_manifest(lake.child(dataset_id)))
        except (SmspaceError, FileNotFoundError) as e:
            broken.append(f"{display_name(dataset_id)}: {e}")
    return manifests, broken


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


def catalog_table(lake: Path | str | Store) -> pa.Table:
    """One row per sound dataset of the lake, from its manifests."""
    return _rows(scan_manifests(lake)[0])


def rebuild_catalog(lake: Path | str | Store) -> pa.Table:
    """The catalog anew from the manifests; a broken dataset is left out, never fatal."""
    lake = _store(lake)
    versions = manifest_versions(lake)
    table = _rows(scan_manifests(lake, list(versions))[0])
    # a dataset whose manifest is broken keeps its version here too: the cache stays valid for it
    meta = {SOURCES_KEY: json.dumps(versions, sort_keys=True).encode()}
    buf = io.BytesIO()
    pq.write_table(table.replace_schema_metadata(meta), buf, compression="zstd")
    lake.put(CATALOG, buf.getvalue())
    return table.replace_schema_metadata(None)


def read_catalog(lake: Path | str | Store) -> pa.Table:
    """The catalog, checked against one listing of the manifests; rebuilt when stale or unreadable.
    A lake that does not exist yet is empty."""
    lake = _store(lake)
    if not lake.is_folder():
        return CATALOG_SCHEMA.empty_table()
    versions = manifest_versions(lake)
    try:
        table = pq.read_table(pa.BufferReader(lake.read_bytes(CATALOG)))  # a BytesIO aborts at exit (pyarrow)
        recorded = json.loads((table.schema.metadata or {}).get(SOURCES_KEY, b"null"))
        table = table.replace_schema_metadata(None)
        if table.schema.equals(CATALOG_SCHEMA) and recorded == versions:
            return table
    except (OSError, pa.ArrowException, SmspaceError, ValueError):
        pass  # missing, unreadable or of an older layout: derive it again
    try:
        return rebuild_catalog(lake)
    except SmspaceError:  # a lake we may not write: list it all the same
        return catalog_table(lake)
