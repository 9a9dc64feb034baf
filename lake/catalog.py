"""The lake-level catalog: one Parquet row per complete dataset, rebuilt from the manifests."""

from __future__ import annotations

import fcntl
import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from common.cli import display_name
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
    try:
        fh = open(lake / LOCK, "a")  # noqa: SIM115 - closed below
    except OSError as e:
        raise SmspaceError(f"cannot lock lake {lake}: {e.strerror or e}") from e
    with fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def scan_manifests(lake: Path) -> tuple[list[Manifest], list[str]]:
    """The sound manifests of a lake, and one line per dataset folder whose manifest is not."""
    manifests, broken = [], []
    for path in sorted(Path(lake).glob(f"*/{MANIFEST}")):
        try:
            manifests.append(load_manifest(path.parent))
        except SmspaceError as e:
            broken.append(f"{display_name(path.parent.name)}: {e}")
    return manifests, broken


def catalog_table(lake: Path) -> pa.Table:
    """One row per sound dataset of the lake, from its manifests."""
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
        for m in scan_manifests(lake)[0]
    ]
    return pa.Table.from_pylist(rows, schema=CATALOG_SCHEMA)


def rebuild_catalog(lake: Path) -> pa.Table:
    """The catalog anew from the manifests; a broken dataset is left out, never fatal."""
    with lake_lock(lake):
        table = catalog_table(lake)
        buf = io.BytesIO()
        pq.write_table(table, buf, compression="zstd")
        write_atomic(Path(lake) / CATALOG, buf.getvalue())
        return table


def read_catalog(lake: Path) -> pa.Table:
    """The catalog; a missing one is empty, an unreadable one is rebuilt from the manifests."""
    path = Path(lake) / CATALOG
    if not path.exists():
        return CATALOG_SCHEMA.empty_table()
    try:
        table = pq.read_table(path)
        if table.schema.equals(CATALOG_SCHEMA):
            return table
    except (OSError, pa.ArrowException):
        pass
    try:
        return rebuild_catalog(lake)
    except SmspaceError:  # a lake we may not write: list it all the same
        return catalog_table(lake)
