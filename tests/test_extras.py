"""Optional extras: a command that needs one that is missing names it in one line; file:// lakes."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import smgen

WITHOUT = """
import sys
sys.modules[{module!r}] = None  # as if the extra were not installed
from smspace.cli import smgen as main
sys.argv = ["smgen", *{args!r}]
main()
"""


def run_without(module: str, *args: str) -> subprocess.CompletedProcess:
    code = WITHOUT.format(module=module, args=list(args))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_a_missing_s3_extra_is_named(tmp_path):
    proc = run_without("s3fs", "ls", "--lake", "s3://bucket/lake")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "pip install 'smspace[s3]'" in proc.stderr


def test_a_missing_cluster_extra_is_named(tmp_path):
    args = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", "100", "--executor", "ray"]
    proc = run_without("ray", *args, "--lake", str(tmp_path / "lake"))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "pip install 'smspace[cluster]'" in proc.stderr
    assert not (tmp_path / "lake").exists()


def test_a_file_url_is_a_local_lake(tmp_path):
    lake = f"file://{tmp_path / 'lake'}"
    result = smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 2000, "--lake", lake)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "lake" / "grid-seed0-MM" / "manifest.json").is_file()
    listing = smgen("ls", "--lake", lake, "--json")
    assert listing.exit_code == 0 and '"grid-seed0-MM"' in listing.output
    assert smgen("validate", "grid-seed0-MM", "--lake", lake).exit_code == 0
