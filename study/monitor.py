"""A study's progress as a whole, from ensembles training in other processes or on Ray: each one
puts (its key, its step) on the executor's channel about every second (train/engine.py, on_step);
this process adds them up into one line (runs finished / running, run-steps per second, ETA)."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from smspace.common.executors import drain_channel
from smspace.common.progress import Progress

POLL_S = 0.5


class StudyMonitor:
    """`ensembles`: key -> (runs in the ensemble, step it starts from, step it ends at)."""

    def __init__(self, ensembles: dict[str, tuple[int, int, int]], enabled: bool = True):
        self.ensembles = ensembles
        self.at = {key: start for key, (_, start, _) in ensembles.items()}
        total = sum(runs * (end - start) for runs, start, end in ensembles.values())
        self.runs = sum(runs for runs, _, _ in ensembles.values())
        self.said: set[str] = set()
        self.bar = Progress("study", total, "run-step", enabled=enabled and total > 0)
        self._show()

    def heard(self, key: str, step: int) -> None:
        if key in self.at:
            self.at[key] = max(self.at[key], step)

    def _show(self) -> None:
        finished = sum(runs for key, (runs, _, end) in self.ensembles.items() if self.at[key] >= end)
        running = sum(
            runs for key, (runs, start, end) in self.ensembles.items() if start < end and start < self.at[key] < end
        )
        done = sum(runs * (self.at[key] - start) for key, (runs, start, _) in self.ensembles.items())
        already = sum(runs for runs, start, end in self.ensembles.values() if start >= end)
        self.bar.set_postfix(runs=f"{finished + already}/{self.runs} finished, {running} running")
        self.bar.set(done)

    def poll(self, channel: Any) -> None:
        for key, step in drain_channel(channel):
            if isinstance(step, str):  # a worker's note (train/precision.py): said once per study
                if step not in self.said:
                    self.said.add(step)
                    print(step, file=sys.stderr, flush=True)
            else:
                self.heard(key, step)
        self._show()

    def close(self) -> None:
        self.bar.close()


@contextmanager
def monitored(monitor: StudyMonitor, channel: Any) -> Iterator[None]:
    """Poll the channel in a thread while the block runs (the block waits on the executor)."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.wait(POLL_S):
            monitor.poll(channel)

    thread = threading.Thread(target=loop, name="study-progress", daemon=True)
    thread.start()
    try:
        yield
        monitor.poll(channel)
    finally:
        stop.set()
        thread.join()
        monitor.close()
