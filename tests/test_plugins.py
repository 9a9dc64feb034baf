"""A package smspace has never seen (examples/plugin-demo, installed by scripts/setup.sh) adds a
setup and a network through entry points: they generate, train alone and in a sweep, view and
report with no edit to smspace, and the runs record the network."""

from __future__ import annotations

import json

import pytest
import torch

from smspace.train.run_dir import RunDir

from .conftest import smgen, smtrain
from .numerics import assert_same_trajectory


@pytest.fixture(scope="module")
def line_lake(tmp_path_factory):
    from smspace.datagen.setups import setup_names
    from smspace.train.config import model_names

    if "line" not in setup_names() or "shallow" not in model_names():
        pytest.fail("examples/plugin-demo is not installed: run `bash scripts/setup.sh`")
    lake = tmp_path_factory.mktemp("line")
    result = smgen("generate", "--setup", "line", "--mode", "all", "--transitions", 3000, "--lake", lake)
    assert result.exit_code == 0, result.output
    return lake


def test_a_plugin_setup_generates_views_and_previews(line_lake, tmp_path):
    manifest = json.loads((line_lake / "line-seed0-MME" / "manifest.json").read_text())
    assert manifest["setup"] == "line" and manifest["network"] == {"encoder_layers": [32, 16]}
    assert smgen("validate", "line-seed0-MEM", "line-seed0-MM", "line-seed0-MME", "--lake", line_lake).exit_code == 0
    view = smgen("view", "line-seed0-MME", "--lake", line_lake, "--save", tmp_path / "line.rrd")
    assert view.exit_code == 0 and (tmp_path / "line.rrd").stat().st_size > 1000, view.output
    assert smgen("preview", "--setup", "line", "--out", tmp_path / "preview").exit_code == 0


def test_a_plugin_network_trains_alone_and_in_a_sweep_the_same_run(line_lake, tmp_path):
    params = '{"width": 24}'
    alone = tmp_path / "alone"
    result = smtrain(
        "fit", "line-seed0-MM", "--lake", line_lake, "--model", "shallow", "--model-params", params,
        "--steps", 60, "--eval-every", 10, "--out", alone,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    cfg = json.loads((alone / "config.json").read_text())
    assert (cfg["model"], cfg["model_params"], cfg["encoder_layers"]) == ("shallow", {"width": 24}, [32, 16])
    state = torch.load(alone / "checkpoint.pt", weights_only=True)["model"]
    assert state["encoder.weight"].shape == (3, 2) and state["predictor.0.weight"].shape == (24, 9)
    runs = tmp_path / "runs"
    result = smtrain(
        "sweep", "--setup", "line", "--modes", "all", "--worlds", 1, "--transitions", 3000, "--model", "shallow",
        "--model-params", params, "--steps", 60, "--eval-every", 10, "--lake", line_lake, "--out", runs,
        "--workers", 1,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    swept = RunDir.open(runs / "line-seed0-MM-nh3-seed0")
    assert (swept.view.config.model, swept.view.config.model_params) == ("shallow", {"width": 24})
    alone_again = RunDir.open(alone)
    assert swept.view.config.seed == alone_again.view.config.seed == 0
    assert_same_trajectory(alone_again.view.metrics(), swept.view.metrics(), "MM")  # tests/numerics.py
    report = smtrain("report", *sorted(p for p in runs.iterdir() if p.is_dir()), "--out", tmp_path / "report")
    assert report.exit_code == 0, report.output
    assert "| line |" in (tmp_path / "report" / "final.md").read_text()
    view = smtrain("view", swept.view.local_path, "--save", tmp_path / "run.rrd")
    assert view.exit_code == 0, view.output


def test_a_network_that_refuses_its_parameters_is_one_line(line_lake, tmp_path):
    result = smtrain(
        "fit", "line-seed0-MM", "--lake", line_lake, "--model", "shallow", "--model-params", '{"depth": 3}',
        "--out", tmp_path / "r",
    )  # fmt: skip
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and "does not take these parameters" in lines[0], result.output
    assert not (tmp_path / "r").exists()
