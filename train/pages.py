"""The pages a command writes into a folder (`smtrain report`'s, `smtrain leaderboard`'s): never
inside the folders it reads, each file written beside and renamed over (a link planted at its name
is replaced, never followed), and what an earlier run of the command wrote there and this one does
not write again removed, so no stale page is read as today's. One set of rules for every page."""

from __future__ import annotations

import html
import io
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

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
        os.fchmod(fh.fileno(), 0o644)  # a page is for reading (a temporary file is made 0600)
    os.replace(fh.name, path)


def write_text(path: Path, text: str) -> None:
    write_atomically(path, text.encode())


def save_figure(fig: Any, path: Path, **options: Any) -> None:
    """A matplotlib figure as PNG, written as every page is (`write_atomically`), then closed."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    try:
        fig.savefig(buffer, format="png", **options)
    finally:
        plt.close(fig)
    write_atomically(path, buffer.getvalue())


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


MARKDOWN = str.maketrans({c: "\\" + c for c in "\\`*_[]|~#"})


def escape(text: str) -> str:
    """A value as a markdown table cell shows it, never as markup: HTML escaped, markdown's
    characters backslashed, line breaks (which names and values cannot hold) refused."""
    if any(c in text for c in "\r\n"):
        raise SmspaceError(f"{text[:40]!r}… holds a line break: it cannot be written in a table")
    return html.escape(text, quote=True).translate(MARKDOWN)
