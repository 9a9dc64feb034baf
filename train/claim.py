"""The one process that trains a run, and every write it makes: claims and file versions in one
place. A local folder is claimed by a lock; on object storage, which has none, each write is
conditional on the version this process last saw or wrote (lake/store.py), so of two writers one
stops in one line instead of both overwriting each other unseen."""

from __future__ import annotations

from smspace.common.errors import SmspaceError
from smspace.common.locks import HeldLock
from smspace.lake.store import Store, WriteConflict

LOCK = ".lock"  # held (flock) by the process training the run


class Claim:
    """The write state of a run folder: unclaimed (writes go straight through, as a run's creator
    and tests do), claimed (locked, every write conditional), or lost to another process."""

    def __init__(self, store: Store, sub_folders: tuple[str, ...]):
        self.store = store
        self.sub_folders = sub_folders
        self._lock: HeldLock | None = None
        # the version of each file this process last saw or wrote (None: absent); None: unclaimed
        self._versions: dict[str, str | None] | None = None
        self.lost = False  # another process took the folder over: this one writes nothing more

    def claim(self) -> None:
        """Become the one process training the run; another one gets a clear refusal."""
        if self._lock is None:
            self._lock = self.store.lock(LOCK, f"{self.store.url} is being trained by another process")
        if self._versions is None:
            found = dict(self.store.fingerprints("*"))
            for sub in self.sub_folders:
                found |= {f"{sub}/{name}": tag for name, tag in self.store.child(sub).fingerprints("*").items()}
            self._versions = found

    def release(self) -> None:
        """Stop being the trainer (to hand the run to another process, which claims it)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        self._versions = None

    def write(self, name: str, data: bytes, sub: str | None = None) -> None:
        """A whole file written; by a claiming process only over the version it last saw (a new
        file: only if still absent). `sub`: one of the run's sub-folders."""
        folder = self.store.child(sub) if sub else self.store
        key = f"{sub}/{name}" if sub else name
        if self._versions is None:
            folder.put(name, data)
            return
        if self.lost:
            raise SmspaceError(f"{self.store.url} is written by another process; this one stopped")
        try:
            self._versions[key] = folder.replace(name, data, self._versions.get(key))
        except WriteConflict:
            self.lost = True
            raise SmspaceError(
                f"{self.store.url}: another process writes this run folder ({key} changed under this one); "
                "this one stopped and left it to the other"
            ) from None

    def delete(self, name: str, sub: str | None = None) -> None:
        (self.store.child(sub) if sub else self.store).delete(name)
        if self._versions is not None:
            self._versions[f"{sub}/{name}" if sub else name] = None
