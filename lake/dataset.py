"""Open a dataset by folder or by id, and read it back into numpy."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from common.errors import SmspaceError
from lake.manifest import MANIFEST, Manifest, load_manifest
from lake.manifest_check import dataset_file
from lake.shards import Block, ShardReader
from lake.transitions import Transitions

DEFAULT_LAKE = Path("data/lake")


def default_lake() -> Path:
    return Path(os.environ.get("SMSPACE_LAKE", DEFAULT_LAKE))


def resolve_dataset(ref: str | Path, lake: Path | None = None) -> Path:
    """DATASET on the command line: a dataset folder, or an id in the lake."""
    path = Path(ref)
    if (path / MANIFEST).exists() or (path.is_dir() and any(path.glob("shard-*"))):
        return path
    candidate = Path(lake or default_lake()) / str(ref)
    if candidate.is_dir():
        return candidate
    raise SmspaceError(
        f"unknown dataset {str(ref)!r}: not a dataset folder, nor an id in lake {lake or default_lake()}"
    )


class Dataset:
    """A complete dataset: its manifest and lazily opened shard readers."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.manifest: Manifest = load_manifest(self.folder)

    @classmethod
    def open(cls, ref: str | Path, lake: Path | None = None) -> Dataset:
        return cls(resolve_dataset(ref, lake))

    def file(self, name: str) -> Path:
        """A file of this dataset, confined to its folder and regular (docs/FORMAT.md)."""
        try:
            return dataset_file(self.folder, name)
        except FileNotFoundError:
            raise SmspaceError(f"missing file {self.folder / name} of dataset {self.manifest.dataset_id}") from None

    def shard_paths(self) -> list[Path]:
        return [self.file(s["file"]) for s in self.manifest.shards]

    def blocks(self) -> Iterator[Block]:
        for path in self.shard_paths():
            with ShardReader(path) as reader:
                yield from reader.blocks()

    def read_all(self, limit: int | None = None) -> Transitions:
        """The first `limit` transitions (all by default) in index order, as numpy arrays; only the
        blocks needed are read (paper-sized sets fit in memory)."""
        parts, have = [], 0
        for block in self.blocks():
            parts.append(block.transitions)
            have += len(block.transitions)
            if limit is not None and have >= limit:
                break
        if not parts:
            raise SmspaceError(f"dataset {self.folder} has no transitions")
        return Transitions.concat(parts)[:limit]

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        with ShardReader(self.file(self.manifest.regular_sampling["file"])) as reader:
            return reader.regular_sampling()
