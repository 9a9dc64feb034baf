"""The lake-level catalog: one Parquet row per complete dataset, rebuilt from the manifests."""

from __future__ import annotations

import fcntl
import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from common.errors import SmspaceError
from lake.atomic import write_atomic
from lake.manifest import MANIFEST, Manifest, load_manifest

CATALOG = "catalog.parquet"
LOCK = ".catalog.lock"

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


def check_lake(lake: Path) -> Path:
    """The lake must be a folder (created if missing); a file there is a user error."""
    lake = Path(lake)
    if lake.exists() and not lake.is_dir():
        raise SmspaceError(f"lake path {lake} is a file, not a folder")
    try:
        lake.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SmspaceError(f"cannot create lake folder {lake}: {e.strerror or e}") from e
    return lake


@contextmanager
def lake_lock(lake: Path) -> Iterator[None]:
    """Serialise catalog rewrites between concurrent smgen processes."""
    with open(lake / LOCK, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def scan_manifests(lake: Path) -> list[Manifest]:
    return [load_manifest(p.parent) for p in sorted(Path(lake).glob(f"*/{MANIFEST}"))]


def rebuild_catalog(lake: Path) -> pa.Table:
    with lake_lock(lake):
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
            for m in scan_manifests(lake)
        ]
        table = pa.Table.from_pylist(rows, schema=CATALOG_SCHEMA)
        buf = io.BytesIO()
        pq.write_table(table, buf, compression="zstd")
        write_atomic(Path(lake) / CATALOG, buf.getvalue())
        return table


def read_catalog(lake: Path) -> pa.Table:
    path = Path(lake) / CATALOG
    if not path.exists():
        return CATALOG_SCHEMA.empty_table()
    return pq.read_table(path)
