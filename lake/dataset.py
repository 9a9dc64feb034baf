"""Open a dataset by folder, URL or id, and read it back into numpy."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from smspace.common.cli import default_lake
from smspace.common.errors import SmspaceError
from smspace.lake.integrity import check_file
from smspace.lake.manifest import GENERATION, MANIFEST, Manifest, load_manifest
from smspace.lake.shards import Block, ShardReader
from smspace.lake.store import Store, exists, is_url, listing, open_store
from smspace.lake.transitions import Transitions


def lake_store(ref: Any) -> Store:
    """The lake named by --lake, or the default one; the API's Lake objects (smspace.open_lake)
    are taken wherever a lake is, by the store they hold."""
    store = getattr(ref, "store", None)
    if isinstance(store, Store):
        return store
    return open_store(ref if ref not in (None, "") else default_lake())


def _is_dataset(store: Store) -> bool:
    return exists(store, MANIFEST) or exists(store, GENERATION) or bool(listing(store, "shard-*"))


def resolve_dataset(ref: str | Path | Store, lake: str | Path | Store | None = None) -> Store:
    """DATASET on the command line: a dataset folder or URL, or an id in the lake."""
    if isinstance(ref, Store):
        return ref
    direct = open_store(ref)
    if _is_dataset(direct):
        return direct
    if not is_url(ref) and "/" not in str(ref) and str(ref) not in ("", ".", ".."):
        candidate = lake_store(lake).child(str(ref))
        if candidate.is_folder():
            return candidate
    raise SmspaceError(f"unknown dataset {str(ref)!r}: not a dataset folder, nor an id in lake {lake_store(lake).url}")


class Dataset:
    """A complete dataset: its manifest and lazily opened shard readers."""

    def __init__(self, where: str | Path | Store):
        self.store: Store = open_store(where)
        self.manifest: Manifest = load_manifest(self.store)
        self._intact: set[str] = set()  # files checked against the manifest in this process

    def verify(self) -> Dataset:
        """Every file checked against the manifest now (one metadata request each on object
        storage, a hash of each local file), so a damaged dataset is refused before work starts."""
        for entry in [*self.manifest.shards, self.manifest.regular_sampling]:
            self._recorded(entry)
        return self

    def _recorded(self, entry: dict) -> str:
        """A file of the dataset, once checked to be the one the manifest records (lake/integrity.py)."""
        name = self._checked(entry["file"])
        if name not in self._intact:
            check_file(self.store, entry, self.manifest.dataset_id)
            self._intact.add(name)
        return name

    @classmethod
    def open(cls, ref: str | Path, lake: str | Path | Store | None = None) -> Dataset:
        return cls(resolve_dataset(ref, lake))

    @property
    def url(self) -> str:
        return self.store.url

    @property
    def local_folder(self) -> Path | None:
        """The folder on this machine, or None for a dataset on object storage."""
        return self.store.local_path

    def _checked(self, name: str) -> str:
        try:
            self.store.size(name)
        except FileNotFoundError:
            raise SmspaceError(f"missing file {self.url}/{name} of dataset {self.manifest.dataset_id}") from None
        return name

    def shard_reader(self, i: int) -> ShardReader:
        """Shard i, checked against its manifest and opened for ranged reads (locally or on object storage)."""
        return ShardReader(self.store, self._recorded(self.manifest.shards[i]))

    def shard_sizes(self) -> list[int]:
        """The stored size of every shard (a missing one is named)."""
        return [self.store.size(self._checked(s["file"])) for s in self.manifest.shards]

    def blocks(self) -> Iterator[Block]:
        for i in range(len(self.manifest.shards)):
            with self.shard_reader(i) as reader:
                yield from reader.blocks()

    def transitions(self, limit: int | None = None) -> Transitions:
        """The first `limit` transitions (all by default), as numpy columns (privileged p and shift
        included: for analysis; the training stream leaves them out)."""
        return self.read_all(limit)

    def _first_blocks(self, limit: int | None) -> list[Block]:
        """The blocks holding the first `limit` transitions (all by default); only those are read."""
        blocks, have = [], 0
        for block in self.blocks():
            blocks.append(block)
            have += len(block.transitions)
            if limit is not None and have >= limit:
                break
        if not blocks:
            raise SmspaceError(f"dataset {self.url} has no transitions")
        return blocks

    @staticmethod
    def _episodes_of(blocks: list[Block], limit: int | None) -> tuple[np.ndarray, np.ndarray] | None:
        if any(b.episode is None or b.step is None for b in blocks):
            return None
        return np.concatenate([b.episode for b in blocks])[:limit], np.concatenate([b.step for b in blocks])[:limit]

    def read_all(self, limit: int | None = None) -> Transitions:
        """The first `limit` transitions (all by default) in index order, as numpy arrays; only the
        blocks needed are read (paper-sized sets fit in memory)."""
        return Transitions.concat([b.transitions for b in self._first_blocks(limit)])[:limit]

    def episodes(self, limit: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """(episode, step) of the first `limit` transitions of a walk dataset; None for independent
        transitions, which have neither."""
        return self._episodes_of(self._first_blocks(limit), limit)

    def read_walk(self, limit: int | None = None) -> tuple[Transitions, tuple[np.ndarray, np.ndarray] | None]:
        """read_all and episodes in one pass over the blocks."""
        blocks = self._first_blocks(limit)
        return Transitions.concat([b.transitions for b in blocks])[:limit], self._episodes_of(blocks, limit)

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        with ShardReader(self.store, self._recorded(self.manifest.regular_sampling)) as reader:
            return reader.regular_sampling()
