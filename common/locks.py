"""Advisory locks (flock) that say who holds them: one writer per dataset and per run folder.

The kernel drops a flock when its holder dies, however it dies, so a lock never outlives a
killed command and needs no cleanup."""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import sys
from pathlib import Path
from typing import IO

from smspace.common.errors import SmspaceError


class HeldLock:
    """An open lock file; the lock lasts until `release` (or the end of a `with` block, or the
    process). Without a file (`None`): a store that has no locks, where nothing is held."""

    def __init__(self, fh: IO[str] | None):
        self._fh = fh

    def release(self) -> None:
        if self._fh is not None:
            self._fh.close()

    def __enter__(self) -> HeldLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _open_lock_file(path: Path) -> IO[str]:
    """The lock file, opened without following a link (a `.lock` made a symlink to another file
    had that file truncated and a pid written into it) and only if it is a plain file (a FIFO
    would block the open: O_NONBLOCK)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o644)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise SmspaceError(f"cannot lock {path}: it is not a plain file; remove it")
    os.set_blocking(fd, True)
    return os.fdopen(fd, "r+")  # kept open: closing it releases the lock


def hold_lock(path: Path, busy: str, wait: bool) -> HeldLock:
    """Lock `path` (created if needed). If another process holds it: wait for it (`wait`), saying so
    once on stderr, or refuse with `busy` and the holder's pid."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = _open_lock_file(path)
    except OSError as e:
        if e.errno == errno.ELOOP:  # O_NOFOLLOW met a link: writing through it would truncate its target
            raise SmspaceError(
                f"cannot lock {path}: it is a symbolic link; remove it (locks are never followed)"
            ) from e
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
