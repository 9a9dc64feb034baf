"""Vectorised ensembles: a run trained inside one is the run trained alone; sweeps and reports."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from train.cli import main as smtrain_main
from train.config import TrainConfig
from train.ensemble import train_ensemble
from train.fit import fit
from train.run_dir import RunDir

from .conftest import SAMPLES


def smtrain(*args):
    return CliRunner().invoke(smtrain_main, [str(a) for a in args], prog_name="smtrain")


def config(mode: str, seed: int, steps: int = 60) -> TrainConfig:
    ds = SAMPLES / f"grid-seed0-{mode}"
    return TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=steps, eval_every=30, seed=seed)


def test_a_run_inside_an_ensemble_is_the_run_trained_alone(tmp_path):
    cfgs = [config("MEM", 11), config("MM", 12), config("MME", 13)]
    members = [RunDir.create(tmp_path / f"ensemble{i}", c, False) for i, c in enumerate(cfgs)]
    train_ensemble(members, progress=False)
    for i, cfg in enumerate(cfgs):
        alone = RunDir.create(tmp_path / f"alone{i}", cfg, False)
        fit(cfg, alone)
        a, b = alone.metrics(), members[i].metrics()
        assert [r["step"] for r in a] == [r["step"] for r in b] == [0, 30, 60]
        assert a[0]["eval_loss"] == pytest.approx(b[0]["eval_loss"], rel=1e-6)  # same initial weights
        for ra, rb in zip(a, b, strict=True):
            for key in ("eval_loss", "d_topo", "d_metric"):
                assert ra[key] == pytest.approx(rb[key], rel=1e-3, abs=1e-6), key
        ca = torch.load(alone.path / "checkpoint.pt", weights_only=True)
        cb = torch.load(members[i].path / "checkpoint.pt", weights_only=True)
        assert ca["model"].keys() == cb["model"].keys()
        for name, tensor in ca["model"].items():
            torch.testing.assert_close(cb["model"][name], tensor, rtol=1e-3, atol=1e-4)
        for key in ("exp_avg", "exp_avg_sq"):  # the Adam state is the lone run's, slice by slice
            torch.testing.assert_close(
                cb["optimizer"]["state"][0][key], ca["optimizer"]["state"][0][key], rtol=1e-2, atol=1e-6
            )
        assert ca["stream"] == cb["stream"]


def test_sweep_generates_trains_resumes_and_reports(tmp_path):
    lake, out = tmp_path / "lake", tmp_path / "runs"
    args = [
        "sweep",
        "--setup",
        "grid",
        "--worlds",
        2,
        "--seed",
        5,
        "--transitions",
        2500,
        "--steps",
        40,
        "--eval-every",
        20,
        "--lake",
        lake,
        "--out",
        out,
    ]
    result = smtrain(*args)
    assert result.exit_code == 0, result.output
    folders = sorted(out.iterdir())
    assert [f.name for f in folders] == [f"grid-seed{w}-{m}-nh3-seed{w}" for w in (5, 6) for m in ("MEM", "MM", "MME")]
    for folder in folders:
        run = RunDir.open(folder)
        assert [r["step"] for r in run.metrics()] == [0, 20, 40] and run.status()["state"] == "finished"
        assert run.embeddings(40)[0].shape == (125, 3)
    before = (folders[0] / "checkpoint.pt").read_bytes()
    assert smtrain(*args).exit_code == 0  # finished runs are left alone
    assert (folders[0] / "checkpoint.pt").read_bytes() == before
    extended = smtrain(*args[:-6], "--steps", 60, "--eval-every", 20, "--lake", lake, "--out", out)
    assert extended.exit_code == 0, extended.output
    assert all(RunDir.open(f).metrics()[-1]["step"] == 60 for f in folders)
    # a sweep run is an ordinary run folder: fit --resume continues it, view and report read it
    resumed = smtrain("fit", "--resume", folders[1], "--steps", 80)
    assert resumed.exit_code == 0, resumed.output
    assert json.loads(resumed.output.strip().splitlines()[-1])["step"] == 80
    refused = smtrain(*args[:-6], "--steps", 60, "--batch-size", 50, "--lake", lake, "--out", out)
    assert refused.exit_code == 2 and "batch_size" in refused.output

    report = tmp_path / "report"
    result = smtrain("report", *folders, "--out", report)
    assert result.exit_code == 0, result.output
    for name in (
        "curves.png",
        "projection_MEM.png",
        "projection_MM.png",
        "projection_MME.png",
        "final.csv",
        "final.md",
        "runs.csv",
    ):
        assert (report / name).stat().st_size > 100, name
    with open(report / "final.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["mode"] for r in rows] == ["MEM", "MM", "MME"] and all(r["runs"] == "2" for r in rows)
    mem = [RunDir.open(f).metrics()[-1]["d_metric"] for f in folders if "-MEM-" in f.name]
    assert float(rows[0]["d_metric_mean"]) == pytest.approx(np.mean(mem))
    assert "| MME | 2 |" in (report / "final.md").read_text()


def test_report_needs_evaluated_runs(tmp_path):
    RunDir.create(tmp_path / "empty", config("MM", 1), False)
    result = smtrain("report", tmp_path / "empty", "--out", tmp_path / "r")
    assert result.exit_code == 2 and "no evaluations" in result.output


@pytest.mark.parametrize("setup", ["grid6", "arm6"])
def test_six_motor_setups_and_nh25_run_through_the_same_commands(tmp_path, setup):
    result = smtrain(
        "sweep",
        "--setup",
        setup,
        "--modes",
        "MME",
        "--worlds",
        1,
        "--transitions",
        1500,
        "--steps",
        10,
        "--eval-every",
        10,
        "--nh",
        25,
        "--lake",
        tmp_path / "lake",
        "--out",
        tmp_path / "runs",
    )
    assert result.exit_code == 0, result.output
    run = RunDir.open(tmp_path / "runs" / f"{setup}-seed0-MME-nh25-seed0")
    h, p = run.embeddings(10)
    assert h.shape == (15625, 25) and p.shape == (15625, 2)
    state = torch.load(run.path / "checkpoint.pt", weights_only=True)["model"]
    assert state["encoder.0.weight"].shape == (500, 6)  # the paper's larger encoder for six motors
    assert np.isfinite(run.metrics()[-1]["d_metric"])


@pytest.mark.slow
def test_a_run_does_not_depend_on_how_a_sweep_groups_or_places_it(tmp_path):
    """The same 6-run sweep as one ensemble here, as 3+3 on two processes, and as 1×6 Ray tasks."""
    import os
    import subprocess

    from tests.conftest import BIN

    lake = tmp_path / "lake"
    base = ["sweep", "--setup", "grid", "--worlds", 2, "--seed", 5, "--transitions", 2500, "--steps", 30]
    base += ["--eval-every", 15, "--lake", lake]
    one = smtrain(*base, "--out", tmp_path / "six", "--max-ensemble", 6, "--workers", 1)
    assert one.exit_code == 0, one.output
    two = smtrain(*base, "--out", tmp_path / "three", "--max-ensemble", 3, "--workers", 2)
    assert two.exit_code == 0, two.output
    from tests.servers import processes_marked

    marker = f"sweep-{os.getpid()}-{tmp_path.name}"
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0", "SMSPACE_TEST_MARK": marker}
    env.pop("RAY_ADDRESS", None)
    ray_args = [*map(str, base), "--out", str(tmp_path / "one"), "--max-ensemble", "1", "--workers", "2"]
    ray = subprocess.run(
        [str(BIN / "smtrain"), *ray_args, "--executor", "ray"], capture_output=True, text=True, env=env, timeout=600
    )
    assert ray.returncode == 0, ray.stderr
    assert processes_marked(marker) == []  # the local Ray the sweep started is gone with it
    names = sorted(p.name for p in (tmp_path / "six").iterdir())
    assert len(names) == 6
    for name in names:
        ref = torch.load(tmp_path / "six" / name / "checkpoint.pt", weights_only=True)
        for grouping in ("three", "one"):
            other = torch.load(tmp_path / grouping / name / "checkpoint.pt", weights_only=True)
            assert other["step"] == ref["step"] == 30
            # float32 sums in another order: most runs agree to 1e-7; Adam's normalised step turns a
            # near-zero gradient's rounding into up to ~3e-4 on single weights after 30 steps
            for key, tensor in ref["model"].items():
                torch.testing.assert_close(other["model"][key], tensor, rtol=1e-3, atol=5e-4)
            a, b = RunDir(tmp_path / "six" / name).metrics(), RunDir(tmp_path / grouping / name).metrics()
            for ra, rb in zip(a, b, strict=True):  # D_topo ranks neighbours: 1e-4 in h moves it most
                for key, rel in (("eval_loss", 1e-3), ("d_topo", 1e-2), ("d_metric", 1e-2)):
                    assert ra[key] == pytest.approx(rb[key], rel=rel, abs=1e-6), key


def test_report_keeps_studies_apart_and_projects_wide_h(tmp_path):
    """Runs of two N_h are two studies: separate curves and rows, never one mean; h of N_h > 3 is
    drawn as its first three principal components."""
    from train.report import first_three

    runs = []
    for n_h in (3, 5):
        for mode in ("MEM", "MM"):
            cfg = replace(config(mode, 7, steps=20), n_h=n_h, eval_every=10)
            run = RunDir.create(tmp_path / f"{mode}-nh{n_h}", cfg, False)
            fit(cfg, run)
            runs.append(run.path)
    result = smtrain("report", *runs, "--out", tmp_path / "report")
    assert result.exit_code == 0, result.output
    names = {p.name for p in (tmp_path / "report").iterdir()}
    assert {"grid-nh3_curves.png", "grid-nh5_curves.png", "grid-nh5_projection_MM.png"} <= names
    with open(tmp_path / "report" / "final.csv") as fh:
        rows = [(r["setup"], r["n_h"], r["mode"], r["runs"]) for r in csv.DictReader(fh)]
    assert rows == [
        ("grid", "3", "MEM", "1"),
        ("grid", "3", "MM", "1"),
        ("grid", "5", "MEM", "1"),
        ("grid", "5", "MM", "1"),
    ]
    table = (tmp_path / "report" / "final.md").read_text()
    assert "| grid | 5 | MM | 1 | 20 |" in table and "±" not in table  # one run has no spread to show
    h = np.random.default_rng(0).normal(size=(50, 5)) * [5, 3, 2, 0.1, 0.1]
    shown, how = first_three(h)
    assert shown.shape == (50, 3) and "PCA to 3 of 5" in how
    assert np.allclose(first_three(h[:, :2])[0][:, 2], 0) and first_three(h[:, :2])[1] == ""
