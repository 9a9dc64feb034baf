"""Stream a lake dataset into training batches: sharded over workers and ranks, shuffled from a
seed, endless if asked, and resumable to the exact same stream.

The unit of work is one batch message (≈1024 transitions; each is its own MCAP chunk). In epoch e
the units are permuted with SeedSequence(seed, (e,)); the g-th of G consumers (G = ranks × DataLoader
workers) takes units g, g+G, … — so within an epoch no transition is read twice or missed. A
consumer shuffles rows inside windows of `window` units and cuts its row stream into batches.
Everything is a function of (seed, g, G, rows consumed), so resuming needs only a batch count.
Only (m_t, s_t, m_t1, s_t1) leave the loader: the privileged ground truth never reaches a model.

Resuming a loop of your own: read in the main process, `state_dict()` counts only the batches the
main process itself drew. Under a DataLoader with workers each worker holds its own copy of the
stream, so checkpoint the loader instead: torchdata's `StatefulDataLoader` collects every worker's
`state_dict()` (its consumer role and the batches it delivered) and gives each its own back on
`load_state_dict` (docs/API.md, "Resuming your own loop").
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from smspace.lake.dataset import Dataset
from smspace.lake.exploration import Exploration, stored_batch
from smspace.lake.manifest import Manifest
from smspace.lake.normalise import normalisers
from smspace.lake.shards import ShardReader

CACHE_BYTES = 64 * 2**20  # a dataset whose normalised columns fit is decoded once per stream


@dataclass(frozen=True)
class Unit:
    shard: int
    first_index: int
    count: int


def dataset_units(manifest: Manifest) -> list[Unit]:
    batch = stored_batch(manifest.config)
    units = []
    for i, shard in enumerate(manifest.shards):
        lo, hi = shard["first_index"], shard["first_index"] + shard["transitions"]
        units += [Unit(i, start, min(batch, hi - start)) for start in range(lo, hi, batch)]
    return units


def walk_length(manifest: Manifest, steps: int) -> int:
    """The episode length windows of `steps` are cut from (0 for transitions, where steps is 1)."""
    walk = Exploration.from_record(manifest.config.get("exploration"))
    if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps: {steps!r}; a whole number from 1")
    if steps > 1 and not walk.walks:
        raise ValueError(f"{manifest.dataset_id} is independent transitions: windows of {steps} steps need walks")
    if steps > 1 and steps > walk.length:
        raise ValueError(f"windows of {steps} steps do not fit in {manifest.dataset_id}'s episodes of {walk.length}")
    return walk.length if walk.walks else 0


def step_windows(rows: np.ndarray, length: int, steps: int) -> np.ndarray:
    """Every window of `steps` consecutive rows within each episode of `length` rows (a unit holds
    whole episodes), each window flattened into one row: step-major, then the row's own columns."""
    episodes = rows.reshape(len(rows) // length, length, rows.shape[1])
    windows = np.lib.stride_tricks.sliding_window_view(episodes, steps, axis=1)  # (E, L - K + 1, W, K)
    return np.ascontiguousarray(windows.transpose(0, 1, 3, 2)).reshape(-1, steps * rows.shape[1])


def _rank(rank: int | None, world: int | None) -> tuple[int, int]:
    if rank is not None and world is not None:
        if world < 1 or not 0 <= rank < world:
            raise ValueError(f"rank {rank} is not in 0 .. {world - 1}")
        return rank, world
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class Batch(NamedTuple):
    """One batch of transitions, float32 and normalised: a tuple (m_t, s_t, m_t1, s_t1) with names.

    From a DataLoader worker it travels as one buffer of bytes through the pipe: as tensors, each
    of the four went through its own shared-memory handle, and the handles, not the data, capped
    the workers at ~450 batches/s (benchmarks/bench_loader_workers.py)."""

    m_t: torch.Tensor
    s_t: torch.Tensor
    m_t1: torch.Tensor
    s_t1: torch.Tensor

    def __reduce__(self):
        if any(t.dtype != torch.float32 for t in self):  # not the stream's own: pickled as it is
            return (Batch, tuple(self))
        data = bytearray(b"".join(t.contiguous().numpy().tobytes() for t in self))
        return (_unpacked, (data, [tuple(t.shape) for t in self]))


def _unpacked(data: bytearray, shapes: list[tuple[int, ...]]) -> Batch:
    flat = torch.frombuffer(data, dtype=torch.float32) if data else torch.empty(0)
    tensors, offset = [], 0
    for shape in shapes:
        n = math.prod(shape)
        tensors.append(flat[offset : offset + n].view(shape))
        offset += n
    return Batch(*tensors)


class TransitionStream(IterableDataset):
    """Yields `Batch`es (m_t, s_t, m_t1, s_t1), float32, normalised with the manifest's statistics."""

    def __init__(
        self,
        dataset: Dataset | str | Path,
        batch_size: int = 100,
        seed: int = 0,
        epochs: int | None = None,
        window: int = 8,
        rank: int | None = None,
        world_size: int | None = None,
        lake: Any = None,
        steps: int = 1,
    ):
        """`dataset`: a Dataset, its folder or URL, or an id in `lake` (a Lake, a folder, URL or
        store; default: $SMSPACE_LAKE or data/lake). rank/world_size default to torch.distributed's
        when it is initialised, else 0 of 1. They are resolved here, in the rank's own process: DataLoader
        workers started by spawn have no process group, and resolving there made every rank read the whole dataset.

        `steps` > 1 (walk datasets only): each sample is K = steps consecutive steps of one episode
        (every window of K steps in it, shuffled like transitions), and each of a batch's four
        tensors gains a step axis: (batch, K, ...), with m_t1[:, k] the m_t of step k + 1."""
        super().__init__()
        self.rank, self.world_size = _rank(rank, world_size)
        self.dataset = dataset if isinstance(dataset, Dataset) else Dataset.open(str(dataset), lake)
        self.batch_size = batch_size
        self.seed = seed
        self.epochs = epochs  # None: sample endlessly (step-based training)
        self.window = window
        self.steps = steps
        self.walk_length = walk_length(self.dataset.manifest, steps)
        self.units = dataset_units(self.dataset.manifest)
        self.m_norm, self.s_norm = normalisers(self.dataset.manifest)
        self.batches_consumed = 0  # batches already delivered before this iterator starts
        # inside a DataLoader worker: (consumer index, consumer count, batches this worker delivered)
        self._consumer: tuple[int, int, int] | None = None
        self._restored_consumer: tuple[int, int, int] | None = None  # from load_state_dict, for the next iterator
        manifest = self.dataset.manifest
        row_bytes = 4 * 2 * (manifest.n_motor + math.prod(manifest.sensor_shape))  # normalised float32
        self._caching = manifest.transitions * row_bytes * steps <= CACHE_BYTES
        self._decoded: dict[Unit, np.ndarray] = {}
        n_m, n_s = manifest.n_motor, math.prod(manifest.sensor_shape)
        edges = np.cumsum([0, n_m, n_s, n_m, n_s])
        self._column_bounds = list(itertools.pairwise(edges.tolist()))  # of m_t, s_t, m_t1, s_t1 in a row

    # -- resumable state ------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Where the stream is: the batches the main process drew; inside a DataLoader worker (as
        StatefulDataLoader asks for it) also this worker's own role and count."""
        state: dict[str, Any] = {"seed": self.seed, "batch_size": self.batch_size}
        if self.steps > 1:  # absent for transitions: states saved before windows existed still load
            state["steps"] = self.steps
        state["batches_consumed"] = self.batches_consumed
        if self._consumer is not None:
            g, n_consumers, delivered = self._consumer
            state["consumer"] = {"index": g, "count": n_consumers, "delivered": delivered}
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["seed"] != self.seed or state["batch_size"] != self.batch_size:
            raise ValueError("stream state belongs to another seed or batch size")
        if int(state.get("steps", 1)) != self.steps:
            raise ValueError(f"stream state of {state.get('steps', 1)}-step windows resumed with {self.steps}")
        self.batches_consumed = int(state["batches_consumed"])
        consumer = state.get("consumer")
        self._restored_consumer = (
            None if consumer is None else (int(consumer["index"]), int(consumer["count"]), int(consumer["delivered"]))
        )

    # -- the stream -------------------------------------------------------------------------
    def _epoch_units(self, epoch: int, g: int, n_consumers: int) -> list[Unit]:
        order = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(epoch,))).permutation(
            len(self.units)
        )
        return [self.units[i] for i in order[g::n_consumers]]

    def _windows(self, g: int, n_consumers: int) -> Iterator[tuple[int, int, list[Unit]]]:
        epoch = 0
        while self.epochs is None or epoch < self.epochs:
            units = self._epoch_units(epoch, g, n_consumers)
            if not units and self.epochs is None and epoch == 0:
                raise ValueError(f"consumer {g} of {n_consumers} has no data: more consumers than batches")
            for w in range(0, len(units), self.window):
                yield epoch, w, units[w : w + self.window]
            epoch += 1

    def _unit_rows(self, readers: dict[int, ShardReader], unit: Unit) -> np.ndarray:
        """A unit's transitions as rows (m_t, s_t, m_t1, s_t1 side by side), normalised; kept in
        memory after the first read when the whole dataset fits in CACHE_BYTES (a grid world's
        150000 transitions take 8 MB): a long run reads each unit a hundred times, and decoding
        it was a third of the loader's time."""
        cached = self._decoded.get(unit)
        if cached is not None:
            return cached
        t = readers[unit.shard].block_at(unit.first_index).transitions
        rows = np.hstack([self.m_norm(t.m_t), self.s_norm(t.s_t), self.m_norm(t.m_t1), self.s_norm(t.s_t1)])
        if self.steps > 1:
            rows = step_windows(rows, self.walk_length, self.steps)
        if self._caching:
            self._decoded[unit] = rows
        return rows

    def _rows(self, readers: dict[int, ShardReader], epoch: int, w: int, g: int, units: list[Unit]) -> np.ndarray:
        """A window's rows in its shuffled order (normalising is per element: before or after the
        shuffle, the same values). Rows move as one: one gather, not one per column."""
        cat = np.concatenate([self._unit_rows(readers, u) for u in units])
        order = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(epoch, w, g, 1))).permutation(
            len(cat)
        )
        return cat.take(order, axis=0)

    def _columns(self, rows: np.ndarray) -> list[torch.Tensor]:
        """m_t, s_t, m_t1, s_t1 of `rows`, each contiguous, all four in one storage: a DataLoader
        worker hands a window's batches over through one shared-memory segment, not four per batch."""
        n, k = len(rows), self.steps
        stepped = rows.reshape(n, k, rows.shape[1] // k) if k > 1 else rows
        flat = torch.empty(rows.size, dtype=torch.float32)
        columns, offset = [], 0
        for a, b in self._column_bounds:
            shape = (n, b - a) if k == 1 else (n, k, b - a)
            column = flat[offset : offset + n * k * (b - a)].view(shape)
            column.numpy()[...] = rows[:, a:b] if k == 1 else stepped[:, :, a:b]
            columns.append(column)
            offset += n * k * (b - a)
        return columns

    def _row_count(self, unit: Unit) -> int:
        """Samples in a unit: its transitions, or its windows of `steps` consecutive steps."""
        if self.steps == 1:
            return unit.count
        return unit.count // self.walk_length * (self.walk_length - self.steps + 1)

    def _role(self) -> tuple[int, int, int]:
        """(consumer index, consumer count, batches this consumer already delivered).

        A DataLoader takes batches from its workers round-robin, starting with worker 0. After
        N batches the next one is due from role N mod W, so on resume worker w plays role
        (w + N) mod W: the merged stream continues exactly where it stopped. A worker whose own
        state was restored (StatefulDataLoader) continues its recorded role instead.
        """
        rank, world = self.rank, self.world_size
        info = get_worker_info()
        w, n_workers = (info.id, info.num_workers) if info else (0, 1)
        restored, self._restored_consumer = self._restored_consumer, None
        if info is not None and restored is not None:
            g, n_consumers, delivered = restored
            if n_consumers != world * n_workers:
                raise ValueError(
                    f"stream state of {n_consumers} consumers resumed by {world * n_workers} "
                    "(ranks x DataLoader workers); resume with as many"
                )
            return g, n_consumers, delivered
        n = self.batches_consumed
        role = (w + n) % n_workers
        delivered = -(-(n - role) // n_workers) if n > role else 0
        return rank * n_workers + role, world * n_workers, delivered

    def __iter__(self) -> Iterator[Batch]:
        g, n_consumers, delivered = self._role()
        info = get_worker_info()
        if info is not None:
            self._consumer = (g, n_consumers, delivered)
        skip_rows = delivered * self.batch_size
        readers: dict[int, ShardReader] = {}
        carry: np.ndarray | None = None  # rows of the previous window short of a whole batch
        try:
            for epoch, w, units in self._windows(g, n_consumers):
                rows = sum(self._row_count(u) for u in units)
                if skip_rows >= rows:  # resuming: whole windows are skipped without reading them
                    skip_rows -= rows
                    continue
                for u in units:
                    if u.shard not in readers:
                        readers[u.shard] = self.dataset.shard_reader(u.shard)
                window = self._rows(readers, epoch, w, g, units)[skip_rows:]
                skip_rows = 0
                if carry is not None:
                    window = np.concatenate([carry, window])
                whole = len(window) // self.batch_size * self.batch_size
                carry = window[whole:]
                # the window's batches cut at once (views of its columns): per batch, nothing is left to do
                batches = (
                    column.view(whole // self.batch_size, self.batch_size, *column.shape[1:]).unbind(0)
                    for column in self._columns(window[:whole])
                )
                for batch in zip(*batches, strict=True):
                    self._count_delivered(info is not None)
                    yield Batch(*batch)
            if carry is not None and len(carry):  # finite streams end with a partial batch
                self._count_delivered(info is not None)
                yield Batch(*self._columns(carry))
        finally:
            for reader in readers.values():
                reader.close()

    def _count_delivered(self, in_worker: bool) -> None:
        """Counted before the batch leaves, so a state taken right after it includes it."""
        if in_worker:
            g, n_consumers, delivered = self._consumer
            self._consumer = (g, n_consumers, delivered + 1)
        else:
            self.batches_consumed += 1
