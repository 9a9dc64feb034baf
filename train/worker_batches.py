"""Batches from DataLoader workers, many per queue item, in the order a DataLoader gives them.

A DataLoader item costs the main process ~0.15 ms of queue whatever it carries, and the stream
hands over a cached batch in ~14 µs: one batch per item, workers made a training loop 12-16 %
slower than none (benchmarks/bench_loader_workers.py). Here each worker sends RUN batches at a
time, stacked, and the main process deals them out round-robin over the workers, skipping those
that are done — the order `DataLoader(stream, batch_size=None, num_workers=W)` gives batch by
batch, so each worker plays the same consumer role and a resume continues the same stream.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from smspace.train.loader import Batch, TransitionStream

RUN = 64  # batches per queue item


class _Runs(IterableDataset):
    """Inside a worker: the stream's batches (its role there, as under a plain DataLoader), RUN at
    a time as one stacked Batch, tagged with the worker; then (worker, None): this one is done."""

    def __init__(self, stream: TransitionStream):
        super().__init__()
        self.stream = stream

    def __iter__(self) -> Iterator[tuple[int, Batch | None]]:
        worker = get_worker_info().id
        run: list[Batch] = []
        for batch in self.stream:
            if run and (len(run) == RUN or len(batch.m_t) != len(run[0].m_t)):  # a short last batch rides alone
                yield worker, _stacked(run)
                run = []
            run.append(batch)
        if run:
            yield worker, _stacked(run)
        yield worker, None


def _stacked(run: list[Batch]) -> Batch:
    return Batch(*(torch.stack(column) for column in zip(*run, strict=True)))


def worker_batches(stream: TransitionStream, num_workers: int) -> Iterator[Batch]:
    """The stream's batches through `num_workers` DataLoader worker processes (0: read here)."""
    if num_workers == 0:
        yield from stream
        return
    waiting: list[deque[Batch]] = [deque() for _ in range(num_workers)]
    done = [False] * num_workers
    items = iter(DataLoader(_Runs(stream), batch_size=None, num_workers=num_workers))
    turn = 0
    while not all(done) or any(waiting):
        while not waiting[turn] and not done[turn]:
            worker, run = next(items)
            if run is None:
                done[worker] = True
            else:
                waiting[worker].extend(Batch(*b) for b in zip(*(c.unbind(0) for c in run), strict=True))
        if waiting[turn]:
            yield waiting[turn].popleft()
        turn = (turn + 1) % num_workers
