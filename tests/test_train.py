"""smtrain fit on the committed samples: learning, resume equivalence, run folders, bad input."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import torch

from smspace.metrics import spatial_scores
from smspace.train.run_dir import RunDir, RunView

from .conftest import BIN, SAMPLES, failed_in_one_line, smtrain


def fit(dataset, out: Path, *extra):
    return smtrain("fit", dataset, "--lake", SAMPLES, "--out", out, *extra)


one_error_line = partial(failed_in_one_line, prog="smtrain")


def test_short_run_learns_and_writes_a_complete_run_folder(tmp_path):
    out = tmp_path / "run"
    result = fit("grid-seed0-MME", out, "--steps", 600, "--eval-every", 200, "--seed", 1)
    assert result.exit_code == 0, result.output
    final = json.loads(result.output.strip().splitlines()[-1])
    run = RunDir.open(out)
    rows = run.view.metrics()
    assert [r["step"] for r in rows] == [0, 200, 400, 600]
    assert final["eval_loss"] == rows[-1]["eval_loss"]
    assert rows[-1]["eval_loss"] < 0.5 * rows[0]["eval_loss"], "the loss must fall"
    assert rows[-1]["d_metric"] < rows[0]["d_metric"]
    assert math.isnan(rows[0]["train_loss"]) and rows[1]["lr"] < rows[0]["lr"]
    # anyone can recompute the metrics from the stored h and p
    h, p = run.view.embeddings(600)
    assert h.shape == (125, 3) and p.shape == (125, 2)
    again = spatial_scores(h.astype(np.float64), p)
    assert again.d_topo == pytest.approx(rows[-1]["d_topo"], rel=1e-5)
    assert again.d_metric == pytest.approx(rows[-1]["d_metric"], rel=1e-5)
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 600 and "encoder.0.weight" in ckpt["model"]
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["steps"] == 600 and cfg["n_h"] == 3 and cfg["lr_decay_steps"] == 480
    assert cfg["dataset_id"] == "grid-seed0-MME"
    assert run.view.status().state == "finished"
    listed = smtrain("ls", "--runs", tmp_path)
    assert "run" in listed.output and "finished" in listed.output
    info = json.loads(smtrain("info", out, "--json").output)
    assert info["step"] == 600 and info["config"]["seed"] == 1


def test_model_defaults_are_the_paper_s(tmp_path):
    from smspace.datagen.setups import get_setup
    from smspace.train.config import TrainConfig
    from smspace.train.engine import build

    def paper(setup: str) -> TrainConfig:
        return TrainConfig(dataset="x", encoder_layers=list(get_setup(setup).encoder_layers))

    from smspace.train.model import Dense

    model, opt = build(paper("grid"), 3, 4, torch.device("cpu"))
    sizes = [m.out_features for m in model.encoder if isinstance(m, Dense)]
    assert sizes == [150, 100, 50, 3]
    sizes = [m.out_features for m in model.predictor if isinstance(m, Dense)]
    assert sizes == [200, 150, 100, 4] and model.predictor[0].in_features == 3 + 3 + 4
    assert all(float(m.bias.detach().abs().max()) == 0 for m in model.encoder if isinstance(m, Dense))
    w = model.encoder[2].weight  # Glorot-uniform bound sqrt(6 / (fan_in + fan_out))
    assert w.shape == (150, 100)  # stored (in, out)
    bound = float(w.detach().abs().max())
    assert 0.9 * math.sqrt(6 / 250) < bound <= math.sqrt(6 / 250)
    six, _ = build(paper("grid6"), 6, 4, torch.device("cpu"))
    assert [m.out_features for m in six.encoder if isinstance(m, Dense)] == [500, 400, 300, 200, 3]
    assert opt.defaults["betas"] == (0.9, 0.999) and opt.defaults["eps"] == 1e-8


def test_learning_rate_schedule():
    from smspace.train.config import TrainConfig
    from smspace.train.engine import learning_rate

    cfg = TrainConfig(dataset="x")
    assert cfg.lr_decay_steps == 80_000
    assert learning_rate(cfg, 0) == 1e-3
    assert learning_rate(cfg, 40_000) == pytest.approx((1e-3 + 1e-5) / 2)
    assert learning_rate(cfg, 80_000) == pytest.approx(1e-5) and learning_rate(cfg, 99_999) == pytest.approx(1e-5)


@pytest.mark.numerical
@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_killed_run_resumes_bit_identical(tmp_path, precision):
    """In either precision: resuming is the same computation, so the same bits."""
    args = ["grid-seed0-MM", "--lake", SAMPLES, "--steps", 2000, "--eval-every", 100, "--seed", 4]
    args += ["--precision", precision]
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
    a, b = RunView.open(clean).metrics(), RunView.open(killed).metrics()
    for row in (*a, *b):
        row.pop("elapsed_s")
    assert len(a) == len(b) == 21
    assert json.dumps(a) == json.dumps(b)  # bit-identical, NaN included
    ca = torch.load(clean / "checkpoint.pt", weights_only=True)
    cb = torch.load(killed / "checkpoint.pt", weights_only=True)
    for name, tensor in ca["model"].items():
        assert torch.equal(tensor, cb["model"][name]), name
    np.testing.assert_array_equal(RunView.open(clean).embeddings(2000)[0], RunView.open(killed).embeddings(2000)[0])
    from .conftest import board_scalars  # the evaluations past the kept checkpoint were dropped

    assert board_scalars(killed) == board_scalars(clean)


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


def test_corrupt_shard_met_during_training_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    """A shard damaged while a run trains (after fit checked the dataset) is met when its reader
    opens it: the run stops in one line, keeping its last checkpoint."""
    from smspace.lake.dataset import Dataset

    from .conftest import smgen

    monkeypatch.setattr(Dataset, "verify", lambda self: self)  # the damage lands after the up-front check
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
    assert RunView.open(out).status().state == "failed"


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
    assert RunView.open(out).config.dataset_id == "grid-seed0-MME"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_without_gpu(tmp_path):
    line = one_error_line(fit("grid-seed0-MM", tmp_path / "r", "--device", "cuda"))
    assert "--device cuda" in line and not (tmp_path / "r").exists()


def test_resume_flags_are_checked(tmp_path):
    assert "is not a run folder" in one_error_line(smtrain("fit", "--resume", tmp_path / "none"))
    assert "DATASET is required" in one_error_line(smtrain("fit"))


def test_more_loader_readers_than_data_is_one_line_before_anything_is_written(tmp_path):
    """1000 transitions are one batch unit: two loader workers (or two ranks) cannot share it."""
    from .conftest import smgen

    lake = tmp_path / "lake"
    assert smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 1000, "--lake", lake).exit_code == 0
    line = one_error_line(
        smtrain("fit", "grid-seed0-MM", "--lake", lake, "--loader-workers", 2, "--out", tmp_path / "r")
    )
    assert "1 batch unit(s)" in line and "--loader-workers" in line and not (tmp_path / "r").exists()
    proc = subprocess.run(
        [
            str(BIN / "smtrain"),
            "fit",
            "grid-seed0-MM",
            "--lake",
            str(lake),
            "--nproc",
            "2",
            "--out",
            str(tmp_path / "d"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr  # said by the launcher, no gloo
    assert "fewer than the 2 readers of 2 process(es)" in proc.stderr and not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--encoder-layers", "150,,50"], "expected comma-separated layer sizes"),
        (["--modes", "MEM,,MM"], "has an empty entry"),
        (["--modes", "MM,MM"], "names a mode twice"),
        (["--modes", "XM"], "unknown mode 'XM'"),
    ],
)
def test_bad_sweep_flags_are_one_line(tmp_path, args, needle):
    result = smtrain("sweep", "--setup", "grid", *args, "--lake", tmp_path / "lake", "--out", tmp_path / "runs")
    assert needle in one_error_line(result)
    assert not (tmp_path / "lake").exists() and not (tmp_path / "runs").exists()


def test_sweep_modes_all_is_every_mode(tmp_path):
    result = smtrain(
        "sweep", "--setup", "grid", "--modes", "all", "--worlds", 1, "--transitions", 1200, "--steps", 2,
        "--eval-every", 2, "--lake", tmp_path / "lake", "--out", tmp_path / "runs", "--workers", 1,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "runs").iterdir() if p.is_dir()) == [
        f"grid-seed0-{m}-nh3-seed0" for m in ("MEM", "MM", "MME")
    ]


def test_a_ray_sweep_without_ray_says_so_before_generating(tmp_path):
    code = (
        "import sys; sys.modules['ray'] = None\n"  # as if the cluster extra were not installed
        "from smspace.cli import smtrain as main\n"
        f"sys.argv = ['smtrain', 'sweep', '--setup', 'grid', '--worlds', '1', '--executor', 'ray', "
        f"'--lake', {str(tmp_path / 'lake')!r}, '--out', {str(tmp_path / 'runs')!r}]\n"
        "main()\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "pip install 'smspace[cluster]'" in proc.stderr
    assert not (tmp_path / "lake").exists() and not (tmp_path / "runs").exists()


def test_a_mistyped_runs_folder_is_not_an_empty_listing(tmp_path):
    line = one_error_line(smtrain("ls", "--runs", tmp_path / "no-such-runs"))
    assert "no run folders at" in line and "no-such-runs" in line
    (tmp_path / "empty").mkdir()
    assert smtrain("ls", "--runs", tmp_path / "empty").exit_code == 0  # an existing folder without runs is empty


def test_ctrl_c_says_which_checkpoint_is_kept_and_how_to_resume(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [str(BIN / "smtrain"), "fit", "grid-seed0-MM", "--lake", str(SAMPLES), "--steps", "100000",
         "--eval-every", "100", "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a terminal
    )  # fmt: skip
    deadline = time.time() + 120
    while time.time() < deadline and not ((out / "checkpoint.pt").exists() and RunView(out).checkpoint_step() >= 200):
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    step = RunView.open(out).checkpoint_step()
    last = stderr.strip().splitlines()[-1]
    assert last == f"interrupted; its checkpoint of step {step} is kept: smtrain fit --resume {out}", stderr
    status = RunView.open(out).status()
    assert status.state == "interrupted" and str(step) in status.message


def test_ctrl_c_of_a_sweep_says_the_same_command_resumes_it(tmp_path):
    out = tmp_path / "runs"
    proc = subprocess.Popen(
        [str(BIN / "smtrain"), "sweep", "--setup", "grid", "--modes", "MM", "--worlds", "2", "--transitions", "2500",
         "--steps", "100000", "--eval-every", "50", "--lake", str(tmp_path / "lake"), "--out", str(out),
         "--workers", "1", "--gen-workers", "1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    deadline = time.time() + 120
    while time.time() < deadline and not list(out.glob("*/checkpoint.pt")):
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == (
        f"interrupted; the runs in {out} keep their last checkpoints and the lake its complete parts: "
        "the same command resumes them"
    )
    assert {RunView.open(p).status().state for p in out.iterdir() if p.is_dir()} == {"interrupted"}


def test_a_run_resumed_from_its_step_0_checkpoint_records_step_0_once(tmp_path, monkeypatch):
    from smspace.train.config import TrainConfig
    from smspace.train.engine import SingleLearner
    from smspace.train.fit import fit as run_fit

    ds = SAMPLES / "grid-seed0-MM"
    cfg = TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=200, eval_every=100, seed=3)
    run = RunDir.create(tmp_path / "run", cfg, False)

    def stop(*args):
        raise KeyboardInterrupt  # after the evaluation and checkpoint of step 0, before step 1

    with monkeypatch.context() as patched:
        patched.setattr(SingleLearner, "train_step", stop)
        with pytest.raises(KeyboardInterrupt):
            run_fit(cfg, run)
    assert run.view.checkpoint_step() == 0 and [r["step"] for r in run.view.metrics()] == [0]
    result = smtrain("fit", "--resume", run.view.local_path)
    assert result.exit_code == 0, result.output
    assert [r["step"] for r in RunView.open(run.view.local_path).metrics()] == [0, 100, 200]


@pytest.mark.numerical
def test_a_checkpoint_of_smspace_0_1_resumes_bit_identical(tmp_path, monkeypatch):
    """Dense weights are stored (in, out) since the ensembles became torch.func: a checkpoint of
    0.1 (weights and Adam moments (out, in), no layout) is converted on resume, exactly."""
    from dataclasses import replace

    from smspace.train.config import TrainConfig
    from smspace.train.engine import SingleLearner
    from smspace.train.fit import fit as run_fit

    ds = SAMPLES / "grid-seed0-MME"
    cfg = TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=40, eval_every=20, seed=5)
    clean = RunDir.create(tmp_path / "clean", cfg, False)
    run_fit(cfg, clean)
    old = RunDir.create(tmp_path / "old", cfg, False)
    real_step, calls = SingleLearner.train_step, []

    def stop_after_20(self, batches, step):
        calls.append(1)
        if len(calls) > 20:
            raise KeyboardInterrupt  # after the checkpoint of step 20
        return real_step(self, batches, step)

    with monkeypatch.context() as patched:
        patched.setattr(SingleLearner, "train_step", stop_after_20)
        with pytest.raises(KeyboardInterrupt):
            run_fit(replace(cfg), old)
    ckpt = torch.load(old.view.local_path / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 20 and ckpt.pop("layout") == "in-out"
    names = list(ckpt["model"])
    for i, name in enumerate(names):  # as smspace 0.1 wrote it
        if ckpt["model"][name].dim() == 2:
            ckpt["model"][name] = ckpt["model"][name].t().contiguous()
            for key in ("exp_avg", "exp_avg_sq"):
                ckpt["optimizer"]["state"][i][key] = ckpt["optimizer"]["state"][i][key].t().contiguous()
    torch.save(ckpt, old.view.local_path / "checkpoint.pt")
    assert smtrain("fit", "--resume", old.view.local_path).exit_code == 0
    a, b = clean.view.metrics(), RunView.open(old.view.local_path).metrics()
    for row in (*a, *b):
        row.pop("elapsed_s")
    assert json.dumps(a) == json.dumps(b)
