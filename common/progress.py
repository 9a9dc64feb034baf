"""Progress that reaches every log: a bar on a terminal, and elsewhere (a file, SLURM, nohup) one
plain line every few seconds, so that a log written for hours is never empty until the end.

The interval of plain lines is $SMSPACE_PROGRESS_EVERY seconds (default 10; 0 turns them off).
"""

from __future__ import annotations

import os
import sys
import time
from collections import deque
from typing import IO, Any

from tqdm import tqdm

EVERY_ENV = "SMSPACE_PROGRESS_EVERY"
DEFAULT_EVERY_S = 10.0
RATE_WINDOW_S = 60.0


def progress_every() -> float:
    try:
        return max(0.0, float(os.environ.get(EVERY_ENV, DEFAULT_EVERY_S)))
    except ValueError:
        return DEFAULT_EVERY_S


def duration(seconds: float) -> str:
    """0:04:05, or ? when unknown."""
    if not (seconds >= 0 and seconds < 1e9):
        return "?"
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Progress:
    """Counts `unit`s towards `total`: a tqdm bar on a terminal, else a line every `every` seconds
    ("training: 1200/6000 steps (20%), 850 steps/s, ETA 0:00:05, loss 0.01 …")."""

    def __init__(
        self,
        desc: str,
        total: int,
        unit: str,
        initial: int = 0,
        enabled: bool = True,
        stream: IO[str] | None = None,
        every: float | None = None,
    ):
        self.desc, self.total, self.unit, self.n = desc, total, unit, initial
        self.stream = stream or sys.stderr
        self.every = progress_every() if every is None else every
        self.postfix: dict[str, Any] = {}
        tty = enabled and self.stream.isatty()
        self.bar = tqdm(total=total, initial=initial, unit=unit, desc=desc, file=self.stream) if tty else None
        self.plain = enabled and not tty and self.every > 0
        self.samples: deque[tuple[float, int]] = deque([(time.monotonic(), initial)])
        self.last_line, self.printed = self.samples[0][0], None

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.plain and time.monotonic() - self.last_line >= self.every:
            self.line()

    def set(self, n: int) -> None:
        """Move to an absolute count (what a monitor of other processes knows)."""
        self.update(n - self.n)

    def set_postfix(self, **values: Any) -> None:
        self.postfix = values
        if self.bar is not None:
            self.bar.set_postfix(**values)

    def rate(self) -> float:
        """Over the last minute or so: a start-up or a slower phase fades from the ETA."""
        now = time.monotonic()
        self.samples.append((now, self.n))
        while len(self.samples) > 2 and now - self.samples[1][0] >= RATE_WINDOW_S:
            self.samples.popleft()
        t0, n0 = self.samples[0]
        return (self.n - n0) / (now - t0) if now > t0 else 0.0

    def line(self) -> None:
        rate = self.rate()
        eta = (self.total - self.n) / rate if rate > 0 else float("nan")
        pct = 100 * self.n / self.total if self.total else 100.0
        parts = [f"{self.desc}: {self.n}/{self.total} {self.unit}s ({pct:.0f}%)", f"{rate:.4g} {self.unit}s/s"]
        parts.append(f"ETA {duration(eta)}")
        parts += [f"{k} {v}" for k, v in self.postfix.items()]
        print(", ".join(parts), file=self.stream, flush=True)
        self.last_line, self.printed = time.monotonic(), (self.n, tuple(self.postfix.items()))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif self.plain and self.printed is not None and self.printed != (self.n, tuple(self.postfix.items())):
            self.line()  # the last state of a command long enough to have been reported (a quick one stays quiet)
