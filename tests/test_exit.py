"""No smspace process aborts at interpreter exit ("terminate called without an active exception",
exit 134: lake/parquet.py says why it happened and what prevents it)."""

from __future__ import annotations

import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

from .conftest import ROOT, SAMPLES, run_cmd

PACKAGE = ("common", "lake", "datagen", "train", "study", "metrics", "smspace")


def test_only_lake_parquet_hands_bytes_to_pyarrow_readers():
    """A Python-owned buffer under an Arrow reader is what aborted at exit: one module reads."""
    wrapped = re.compile(r"pa\.BufferReader\(|pa\.py_buffer\(|pq\.read_(table|schema|metadata)\(|ParquetFile\(")
    found = [
        f"{path.relative_to(ROOT)}:{n}"
        for folder in PACKAGE
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path.relative_to(ROOT).as_posix() != "lake/parquet.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if wrapped.search(line) and "export" not in path.name  # export reads a file by its path
    ]
    assert not found, found


def test_reading_a_run_then_exiting_never_aborts(tmp_path):
    """The reproduction: 24 short processes that read a finished run's metrics (4 in 20 aborted)."""
    run = tmp_path / "run"
    trained = run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", run, "--steps", 20,
                      "--eval-every", 10)  # fmt: skip
    assert trained.returncode == 0, trained.stderr
    code = f"import smspace; smspace.open_run({str(run)!r}).metrics()"

    def once(_: int) -> tuple[int, str]:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        return done.returncode, done.stderr[-300:]

    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(once, range(24)))
    failed = [r for r in results if r[0] != 0]
    assert not failed, f"{len(failed)} of 24 exited non-zero: {failed[:2]}"
