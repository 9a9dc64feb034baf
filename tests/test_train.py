"""smtrain fit on the committed samples: learning, resume equivalence, run folders, bad input."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from metrics import spatial_scores
from train.cli import main as smtrain_main
from train.run_dir import RunDir

from .conftest import BIN, SAMPLES


def smtrain(*args):
    return CliRunner().invoke(smtrain_main, [str(a) for a in args], prog_name="smtrain")


def fit(dataset, out: Path, *extra):
    return smtrain("fit", dataset, "--lake", SAMPLES, "--out", out, *extra)


def one_error_line(result) -> str:
    assert result.exit_code != 0, result.output
    lines = result.output.strip().splitlines()
    assert lines and lines[-1].startswith("smtrain: error: "), result.output
    return lines[-1]


def test_short_run_learns_and_writes_a_complete_run_folder(tmp_path):
    out = tmp_path / "run"
    result = fit("grid-seed0-MME", out, "--steps", 600, "--eval-every", 200, "--seed", 1)
    assert result.exit_code == 0, result.output
    final = json.loads(result.output.strip().splitlines()[-1])
    run = RunDir.open(out)
    rows = run.metrics()
    assert [r["step"] for r in rows] == [0, 200, 400, 600]
    assert final["eval_loss"] == rows[-1]["eval_loss"]
    assert rows[-1]["eval_loss"] < 0.5 * rows[0]["eval_loss"], "the loss must fall"
    assert rows[-1]["d_metric"] < rows[0]["d_metric"]
    assert math.isnan(rows[0]["train_loss"]) and rows[1]["lr"] < rows[0]["lr"]
    # anyone can recompute the metrics from the stored h and p
    h, p = run.embeddings(600)
    assert h.shape == (125, 3) and p.shape == (125, 2)
    again = spatial_scores(h.astype(np.float64), p)
    assert again.d_topo == pytest.approx(rows[-1]["d_topo"], rel=1e-5)
    assert again.d_metric == pytest.approx(rows[-1]["d_metric"], rel=1e-5)
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 600 and "encoder.0.weight" in ckpt["model"]
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["steps"] == 600 and cfg["n_h"] == 3 and cfg["lr_decay_steps"] == 480
    assert cfg["dataset_id"] == "grid-seed0-MME"
    assert run.status()["state"] == "finished"
    listed = smtrain("ls", "--runs", tmp_path)
    assert "run" in listed.output and "finished" in listed.output
    info = json.loads(smtrain("info", out, "--json").output)
    assert info["step"] == 600 and info["config"]["seed"] == 1


def test_model_defaults_are_the_paper_s(tmp_path):
    from train.config import TrainConfig, default_encoder_layers
    from train.fit import build

    def paper(setup: str) -> TrainConfig:
        return TrainConfig(dataset="x", encoder_layers=list(default_encoder_layers(setup)))

    model, opt = build(paper("grid"), 3, 4, torch.device("cpu"))
    sizes = [m.out_features for m in model.encoder if isinstance(m, torch.nn.Linear)]
    assert sizes == [150, 100, 50, 3]
    sizes = [m.out_features for m in model.predictor if isinstance(m, torch.nn.Linear)]
    assert sizes == [200, 150, 100, 4] and model.predictor[0].in_features == 3 + 3 + 4
    assert all(float(m.bias.detach().abs().max()) == 0 for m in model.encoder if isinstance(m, torch.nn.Linear))
    w = model.encoder[2].weight  # Glorot-uniform bound sqrt(6 / (fan_in + fan_out))
    bound = float(w.detach().abs().max())
    assert 0.9 * math.sqrt(6 / 250) < bound <= math.sqrt(6 / 250)
    six, _ = build(paper("grid6"), 6, 4, torch.device("cpu"))
    assert [m.out_features for m in six.encoder if isinstance(m, torch.nn.Linear)] == [500, 400, 300, 200, 3]
    assert opt.defaults["betas"] == (0.9, 0.999) and opt.defaults["eps"] == 1e-8


def test_learning_rate_schedule():
    from train.config import TrainConfig, learning_rate

    cfg = TrainConfig(dataset="x")
    assert cfg.lr_decay_steps == 80_000
    assert learning_rate(cfg, 0) == 1e-3
    assert learning_rate(cfg, 40_000) == pytest.approx((1e-3 + 1e-5) / 2)
    assert learning_rate(cfg, 80_000) == pytest.approx(1e-5) and learning_rate(cfg, 99_999) == pytest.approx(1e-5)


@pytest.mark.numerical
def test_killed_run_resumes_bit_identical(tmp_path):
    args = ["grid-seed0-MM", "--lake", SAMPLES, "--steps", 2000, "--eval-every", 100, "--seed", 4]
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    assert smtrain("fit", *args, "--out", clean).exit_code == 0
    proc = subprocess.Popen(
        [str(BIN / "smtrain"), "fit", *map(str, args), "--out", str(killed)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        try:
            if json.loads((killed / "status.json").read_text())["step"] >= 300:
                break
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    at_kill = torch.load(killed / "checkpoint.pt", weights_only=True)["step"]
    assert 300 <= at_kill < 2000, "the kill must land mid-run"
    refused = smtrain("fit", *args, "--out", killed)
    assert "--resume" in one_error_line(refused)
    resumed = smtrain("fit", "--resume", killed)
    assert resumed.exit_code == 0, resumed.output
    a, b = RunDir.open(clean).metrics(), RunDir.open(killed).metrics()
    for row in (*a, *b):
        row.pop("elapsed_s")
    assert len(a) == len(b) == 21
    assert json.dumps(a) == json.dumps(b)  # bit-identical, NaN included
    ca = torch.load(clean / "checkpoint.pt", weights_only=True)
    cb = torch.load(killed / "checkpoint.pt", weights_only=True)
    for name, tensor in ca["model"].items():
        assert torch.equal(tensor, cb["model"][name]), name
    np.testing.assert_array_equal(RunDir.open(clean).embeddings(2000)[0], RunDir.open(killed).embeddings(2000)[0])


@pytest.mark.numerical
def test_same_seed_same_run_other_seed_other_run(tmp_path):
    a = fit("grid-seed0-MEM", tmp_path / "a", "--steps", 100, "--eval-every", 100, "--seed", 7)
    b = fit("grid-seed0-MEM", tmp_path / "b", "--steps", 100, "--eval-every", 100, "--seed", 7)
    c = fit("grid-seed0-MEM", tmp_path / "c", "--steps", 100, "--eval-every", 100, "--seed", 8)
    last = [json.loads(r.output.strip().splitlines()[-1]) for r in (a, b, c)]
    assert last[0] == last[1] and last[0] != last[2]


# -- bad input -----------------------------------------------------------------------------------


def test_missing_dataset(tmp_path):
    line = one_error_line(smtrain("fit", "grid-seed42-MM", "--lake", tmp_path, "--out", tmp_path / "r"))
    assert "grid-seed42-MM" in line and not (tmp_path / "r").exists()


def test_unsupported_schema_version(tmp_path):
    ds = tmp_path / "grid-seed0-MM"
    shutil.copytree(SAMPLES / "grid-seed0-MM", ds)
    raw = json.loads((ds / "manifest.json").read_text())
    raw["schema_version"] = 7
    (ds / "manifest.json").write_text(json.dumps(raw))
    line = one_error_line(smtrain("fit", ds, "--out", tmp_path / "r"))
    assert "schema version 7" in line


def test_corrupt_shard_met_during_training_keeps_the_last_checkpoint(tmp_path):
    from .conftest import smgen

    assert (
        smgen(
            "generate",
            "--setup",
            "grid",
            "--mode",
            "MME",
            "--transitions",
            20000,
            "--shard-size",
            4096,
            "--lake",
            tmp_path,
        ).exit_code
        == 0
    )
    ds = tmp_path / "grid-seed0-MME"
    shard = ds / "shard-00003.mcap"  # evaluation reads shard 0; training meets this one
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0x5A  # same size: only reading the chunk finds it
    shard.write_bytes(bytes(data))
    out = tmp_path / "run"
    line = one_error_line(smtrain("fit", ds, "--out", out, "--steps", 500, "--eval-every", 10))
    assert "shard-00003.mcap" in line
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] % 10 == 0 and ckpt["step"] < 500
    assert RunDir.open(out).status()["state"] == "failed"


def test_nan_loss_stops_and_says_so(tmp_path):
    out = tmp_path / "run"
    result = fit("grid-seed0-MEM", out, "--steps", 300, "--eval-every", 50, "--lr-start", 1e12, "--lr-end", 1e12)
    line = one_error_line(result)
    assert "NaN" in line and result.exit_code == 1
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert all(torch.isfinite(t).all() for t in ckpt["model"].values())


def test_output_folder_holding_another_run(tmp_path):
    out = tmp_path / "run"
    assert fit("grid-seed0-MM", out, "--steps", 20, "--eval-every", 10).exit_code == 0
    before = (out / "checkpoint.pt").read_bytes()
    line = one_error_line(fit("grid-seed0-MME", out, "--steps", 20))
    assert "--resume" in line and "--overwrite" in line
    assert (out / "checkpoint.pt").read_bytes() == before
    assert fit("grid-seed0-MME", out, "--steps", 20, "--eval-every", 10, "--overwrite").exit_code == 0
    assert RunDir.open(out).config.dataset_id == "grid-seed0-MME"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_without_gpu(tmp_path):
    line = one_error_line(fit("grid-seed0-MM", tmp_path / "r", "--device", "cuda"))
    assert "--device cuda" in line and not (tmp_path / "r").exists()


def test_resume_flags_are_checked(tmp_path):
    assert "is not a run folder" in one_error_line(smtrain("fit", "--resume", tmp_path / "none"))
    assert "DATASET is required" in one_error_line(smtrain("fit"))
