"""The pages a command writes into a folder (`smtrain report`'s, `smtrain leaderboard`'s): never
inside the folders it reads, each file written beside and renamed over (a link planted at its name
is replaced, never followed), and what an earlier run of the command wrote there and this one does
not write again removed, so no stale page is read as today's. One set of rules for every page."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

from smspace.common.errors import SmspaceError
from smspace.lake.store import within


def refuse_inside(out: Path, inputs: Sequence[str | Path], verb: str = "reports on") -> None:
    for path in inputs:
        if within(out, path):  # its pages would be written into what it reads
            raise SmspaceError(f"--out {out} lies inside {path}, which it {verb}; choose another")


def write_atomically(path: Path, data: bytes) -> None:
    """Written beside and renamed over: a link planted at `path` is replaced, never followed."""
    with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", delete=False) as fh:
        fh.write(data)
    os.replace(fh.name, path)


def recorded_files(out: Path, record: str) -> set[str]:
    """What an earlier run wrote into `out` (its record), never anything else found there: paths
    below `out`, none leaving it."""
    try:
        names = json.loads((out / record).read_text()).get("files", [])
    except (FileNotFoundError, ValueError, AttributeError, OSError):
        return set()
    return {n for n in names if isinstance(n, str) and n and not n.startswith("/") and ".." not in n.split("/")}


def record_files(out: Path, record: str, earlier: set[str], files: Sequence[Path]) -> None:
    """Remove what the earlier run wrote and this one did not, then record this run's files."""
    names = {f.relative_to(out).as_posix() for f in files}
    for name in sorted(earlier - names):
        target = out / name
        if not target.is_symlink() and target.is_file():
            target.unlink(missing_ok=True)
    write_atomically(out / record, (json.dumps({"files": sorted(names)}, indent=1) + "\n").encode())
