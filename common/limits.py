"""A bound on code that may never return (a researcher's model that blocks): SIGALRM in the main
thread raises the caller's error when the bound passes. Elsewhere (a thread, a platform without
setitimer) nothing is bounded, and nothing changes."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator

STEP_LIMIT_ENV = "SMSPACE_STEP_LIMIT_S"
DEFAULT_STEP_LIMIT_S = 600.0  # one training step of any setup here takes well under a second on a CPU


def step_limit_s() -> float:
    """The bound on one step of a model's code, in seconds ($SMSPACE_STEP_LIMIT_S; 0: none)."""
    raw = os.environ.get(STEP_LIMIT_ENV, "")
    try:
        value = float(raw) if raw else DEFAULT_STEP_LIMIT_S
    except ValueError:
        value = DEFAULT_STEP_LIMIT_S
    return value if value >= 0 else DEFAULT_STEP_LIMIT_S


@contextlib.contextmanager
def time_limit(seconds: float, error: Callable[[], BaseException]) -> Iterator[None]:
    """Raise `error()` inside the block if it runs longer than `seconds` (0: no bound)."""
    usable = seconds > 0 and hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
    if not usable:
        yield
        return

    def expire(signum, frame):
        raise error()

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
