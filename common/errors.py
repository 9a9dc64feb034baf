"""One exception type for every user-facing failure, so the CLIs can print one line and exit 2."""

from __future__ import annotations


def one_line(e: BaseException | str, limit: int = 200, with_type: bool = False) -> str:
    """An exception (or a message) as one short line, whatever library raised it and whatever
    newlines it held: what every one-line error of smspace is made of."""
    text = " ".join(str(e).split())[:limit]
    if isinstance(e, BaseException) and (with_type or not text):
        return f"{type(e).__name__}: {text}" if text else type(e).__name__
    return text


class SmspaceError(Exception):
    """Bad input or a broken dataset: the message is shown to the user as is."""

    exit_code = 2


class DatasetCorrupt(SmspaceError):
    """A shard or manifest that cannot be trusted (truncated, bit-flipped, inconsistent)."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM, with what was kept and the command that continues: the CLIs print the
    message in one line (exit 130) instead of a bare "interrupted"."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message
