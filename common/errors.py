"""One exception type for every user-facing failure, so the CLIs can print one line and exit 2."""

from __future__ import annotations


class SmspaceError(Exception):
    """Bad input or a broken dataset: the message is shown to the user as is."""

    exit_code = 2


class DatasetCorrupt(SmspaceError):
    """A shard or manifest that cannot be trusted (truncated, bit-flipped, inconsistent)."""
