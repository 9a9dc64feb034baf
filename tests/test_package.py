"""The installable package: a wheel puts only `smspace` in site-packages, and the commands and the
Python API work from any folder, one holding a researcher's own train.py and metrics.py included."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from .conftest import ROOT, SAMPLES

pytestmark = pytest.mark.slow

API = f"""
import smspace, train, metrics
assert train.MINE and metrics.MINE  # the researcher's own modules, not ours
ds = smspace.load_dataset("grid-seed0-MME", lake={str(SAMPLES)!r})
run = smspace.fit(ds, out="run", steps=20, eval_every=10)
print(json.dumps({{"file": smspace.__file__, "steps": [r["step"] for r in run.metrics()]}}))
"""


def test_the_wheel_installs_only_smspace_and_works_from_any_folder(tmp_path):
    dist = tmp_path / "dist"
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert built.returncode == 0, built.stderr
    (wheel,) = dist.glob("smspace-*.whl")
    files = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in files if not n.endswith(".dist-info/RECORD")} - {"smspace"} == {
        next(n.split("/")[0] for n in files if ".dist-info/" in n)
    }  # smspace and its metadata, nothing else
    assert "smspace/schemas/transitions.proto" in files
    assert any(n.startswith("smspace/datagen/setups/arm/shaders/lambert/") for n in files)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    site = Path(sysconfig.get_path("purelib", vars={"base": str(venv), "platbase": str(venv)}))
    # the dependencies come from this environment (appended after the venv's own site-packages);
    # its editable smspace is not active there: its finder is only loaded by this environment's .pth
    (site / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    before = {p.name for p in site.iterdir()}
    installed = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert installed.returncode == 0, installed.stderr
    added = {p.name for p in site.iterdir()} - before
    assert {n for n in added if not n.endswith(".dist-info") and n != "__pycache__"} == {"smspace"}, added

    elsewhere = tmp_path / "my-project"
    elsewhere.mkdir()
    (elsewhere / "train.py").write_text("MINE = True\n")
    (elsewhere / "metrics.py").write_text("MINE = True\n")
    for command in ("smgen", "smtrain"):
        result = subprocess.run([str(venv / "bin" / command), "--help"], capture_output=True, text=True, cwd=elsewhere)
        assert result.returncode == 0 and "Usage:" in result.stdout, result.stderr
    api = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import json\n" + API],
        capture_output=True,
        text=True,
        cwd=elsewhere,
        timeout=300,
    )
    assert api.returncode == 0, api.stderr
    out = json.loads(api.stdout.strip().splitlines()[-1])
    assert out["file"].startswith(str(site)) and out["steps"] == [0, 10, 20]
