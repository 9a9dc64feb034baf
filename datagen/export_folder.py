"""The folder exports (hf, minari) share one way of writing: build under a temporary name beside
--out, rename only when complete, leave nothing after a failure; --overwrite replaces only a folder
an earlier export made (it holds smspace.json, the dataset's manifest), never any other folder."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset

MARKER = "smspace.json"  # the manifest, in every folder these exports write


def check_out(out: Path, overwrite: bool, reads: Path | None, what: str) -> None:
    """Refuse an --out inside what is read, an existing one without --overwrite, and a folder that
    is not an earlier export of ours (`what` names the format in the message)."""
    if reads is not None and out.resolve().is_relative_to(Path(reads).resolve()):
        raise SmspaceError(f"{out} is inside {reads}, which this command reads; write it elsewhere")
    if out.exists() or out.is_symlink():
        if not overwrite:
            raise SmspaceError(f"{out} exists; pass --overwrite to replace it")
        if out.is_symlink() or not (out / MARKER).is_file():
            raise SmspaceError(f"{out} is not an smspace {what} export (no {MARKER}); --overwrite replaces only those")


@contextmanager
def built_folder(ds: Dataset, out: Path, overwrite: bool, what: str) -> Iterator[Path]:
    """A fresh folder to fill; once the body returns it gets the marker and becomes `out`."""
    out = Path(out)
    check_out(out, overwrite, ds.local_folder, what)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    except OSError as e:
        raise SmspaceError(f"cannot write {out}: {e.strerror or e}") from e
    try:
        folder = work / "export"
        folder.mkdir()
        yield folder
        (folder / MARKER).write_text(ds.manifest.to_json())
        if out.exists():
            shutil.rmtree(out)
        folder.rename(out)
    except OSError as e:
        raise SmspaceError(f"cannot write {out}: {e.strerror or e}") from e
    finally:
        shutil.rmtree(work, ignore_errors=True)
