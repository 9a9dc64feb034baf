"""Advisory locks (flock) that say who holds them: one writer per dataset and per run folder.

The kernel drops a flock when its holder dies, however it dies, so a lock never outlives a
killed command and needs no cleanup."""

from __future__ import annotations

import fcntl
import os
import sys
from pathlib import Path
from typing import IO

from smspace.common.errors import SmspaceError


class HeldLock:
    """An open lock file; the lock lasts as long as this object (or the process)."""

    def __init__(self, fh: IO[str]):
        self._fh = fh

    def release(self) -> None:
        self._fh.close()


def hold_lock(path: Path, busy: str, wait: bool) -> HeldLock:
    """Lock `path` (created if needed). If another process holds it: wait for it (`wait`), saying so
    once on stderr, or refuse with `busy` and the holder's pid."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path, "a+")  # noqa: SIM115 - kept open: closing it releases the lock
    except OSError as e:
        raise SmspaceError(f"cannot lock {path}: {e.strerror or e}") from e
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        holder = fh.read().strip() or "?"
        if not wait:
            fh.close()
            raise SmspaceError(f"{busy} (pid {holder})") from None
        print(f"waiting: {busy} (pid {holder})", file=sys.stderr, flush=True)
        fcntl.flock(fh, fcntl.LOCK_EX)
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return HeldLock(fh)
