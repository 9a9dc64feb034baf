"""Whether a process recorded by id still runs on this host: a run's status (train/status.py) and
a bench's temporary folders (bench/run.py) name the process that wrote them."""

from __future__ import annotations

import os


def alive(pid: int | None) -> bool:
    """True while process `pid` exists here (another user's counts). 0 and negative ids are never
    a process: kill(0) would ask about our own process group."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    except OverflowError:  # an id no process can have
        return False
    return True
