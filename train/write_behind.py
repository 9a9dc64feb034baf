"""Run-folder writes done by one thread while the next steps train.

An ensemble's evaluation writes about ten files per run, each made durable (fsync of the file and
of its folder): on a busy machine that was a tenth of a sweep's wall time, nearly all of it
waiting on the disk, which a second thread overlaps with the steps. One thread keeps the order of
the writes, so a kill still leaves every checkpoint at or behind what was written before it. At
most one evaluation is in flight: the next one waits for it, so a kill loses at most the last
evaluation (resume goes back to the checkpoint before it, as after any kill). An error of a write
surfaces in the trainer at the next evaluation or at `drain`, never later and never lost.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor


class WriteBehind:
    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="smspace-run-writes")
        self._pending: list[Future[None]] = []
        self._error: BaseException | None = None

    def submit(self, write: Callable[[], None]) -> None:
        """Queue a write; after one failed, the queued ones are skipped, as the trainer's own
        thread would have stopped at the first."""

        def guarded() -> None:
            if self._error is not None:
                return
            try:
                write()
            except BaseException as e:
                self._error = e

        self._pending.append(self._pool.submit(guarded))

    def drain(self) -> None:
        """Wait for every write submitted; the first one that failed raises its error here."""
        pending, self._pending = self._pending, []
        for future in pending:
            future.result()
        error, self._error = self._error, None
        if error is not None:
            raise error

    def close(self) -> None:
        """Drain, then end the thread (an error raises here as in `drain`)."""
        try:
            self.drain()
        finally:
            self._pool.shutdown(wait=True)
