"""A run and a dataset say exactly what made them (common/provenance.py), and `smtrain info` and
`smtrain report` show it."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import torch

from smspace.train.run_dir import RunView

from .conftest import ROOT, SAMPLES, smtrain


def test_each_training_session_is_recorded_and_shown(tmp_path):
    out = tmp_path / "run"
    first = smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 100, "--eval-every", 50)
    assert first.exit_code == 0, first.output
    resumed = smtrain("fit", "--resume", out, "--steps", 150)
    assert resumed.exit_code == 0, resumed.output
    sessions = RunView.open(out).config.sessions
    assert len(sessions) == 2
    for session in sessions:
        assert session["torch"] == torch.__version__ and session["device"] == "cpu" and session["threads"] == 1
        assert session["smspace"] not in ("", "unknown") and session["cpu"]
        assert session["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
        assert set(session["cpu_vector_extensions"]) <= set(Path("/proc/cpuinfo").read_text().split())
    if (ROOT / ".git").exists():
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
        assert sessions[0]["git_commit"].startswith(head.stdout.strip())

    info = smtrain("info", out)
    assert info.exit_code == 0, info.output
    assert "session 1:" in info.output and "session 2:" in info.output and f"torch {torch.__version__}" in info.output
    assert "dataset made: python" in info.output and "numpy" in info.output
    as_json = json.loads(smtrain("info", out, "--json").output)
    assert as_json["dataset_software"]["numpy"] and len(as_json["config"]["sessions"]) == 2


def test_report_is_one_page_of_a_study_folder(tmp_path):
    """A study folder (its runs found inside it) gives report.md: tables, provenance and figures."""
    runs = tmp_path / "study"
    for mode in ("MM", "MME"):
        args = ["--lake", SAMPLES, "--out", runs / f"r-{mode}", "--steps", 60, "--eval-every", 30]
        result = smtrain("fit", f"grid-seed0-{mode}", *args)
        assert result.exit_code == 0, result.output
    (runs / "study.json").write_text("{}")  # what a sweep leaves beside its runs is not a run
    out = tmp_path / "report"
    result = smtrain("report", runs, "--out", out)
    assert result.exit_code == 0, result.output
    page = (out / "report.md").read_text()
    assert "## grid-nh3: grid, N_h = 3, 1 world(s), 60 steps" in page
    assert "| MM | 1 | 60 |" in page and "| MME | 1 | 60 |" in page
    assert "| mode | runs | step | loss | D_topo ↓ | D_metric ↓ |" in page  # directions from metrics/scores.py
    assert f"- torch: {torch.__version__}" in page and "- datasets made with: python" in page
    images = [line[line.index("(") + 1 : -1] for line in page.splitlines() if line.startswith("![")]
    assert sorted(images) == ["curves.png", "projection_MM.png", "projection_MME.png"]
    assert all((out / name).stat().st_size > 10_000 for name in images)
    bad = smtrain("report", runs / "study.json", "--out", out)
    assert bad.exit_code == 2 and "is a file, not a run folder" in bad.output
