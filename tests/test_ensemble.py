"""Vectorised ensembles: a run trained inside one is the run trained alone; sweeps and reports."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from smspace.common.errors import SmspaceError
from smspace.train.config import TrainConfig
from smspace.train.fit import fit, train_ensemble
from smspace.train.run_dir import RunDir, RunView

from .conftest import SAMPLES, smtrain
from .numerics import assert_same_trajectory, assert_same_weights, relative_distance


def config(mode: str, seed: int, steps: int = 60, eval_every: int = 10) -> TrainConfig:
    ds = SAMPLES / f"grid-seed0-{mode}"
    return TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=steps, eval_every=eval_every, seed=seed)


def checkpoint(run: RunDir) -> dict:
    return torch.load(run.view.local_path / "checkpoint.pt", weights_only=True)


@pytest.mark.numerical
def test_a_run_inside_an_ensemble_is_the_run_trained_alone(tmp_path):
    """The same run to the tolerance tests/numerics.py states for its mode, on any CPU kind."""
    cfgs = [config("MEM", 11), config("MM", 12), config("MME", 13)]
    members = [RunDir.create(tmp_path / f"ensemble{i}", c, False) for i, c in enumerate(cfgs)]
    train_ensemble(members, progress=False)
    for i, cfg in enumerate(cfgs):
        mode = cfg.dataset_id.rsplit("-", 1)[1]
        alone = RunDir.create(tmp_path / f"alone{i}", cfg, False)
        fit(cfg, alone)
        assert [r["step"] for r in alone.view.metrics()] == list(range(0, 61, 10))
        assert_same_trajectory(alone.view.metrics(), members[i].view.metrics(), mode)
        ca, cb = checkpoint(alone), checkpoint(members[i])
        assert_same_weights(ca["model"], cb["model"], mode)
        if mode != "MEM":  # the Adam state is the lone run's, slice by slice
            for key in ("exp_avg", "exp_avg_sq"):
                a_state, b_state = ca["optimizer"]["state"][0][key], cb["optimizer"]["state"][0][key]
                assert relative_distance(a_state, b_state) < 5e-2, key
        assert ca["stream"] == cb["stream"]


@pytest.mark.numerical
def test_an_ensemble_starts_from_the_lone_runs_weights_and_repeats_bit_for_bit(tmp_path):
    """Exact where the computation is the same: the initial weights, and the same ensemble re-run."""
    from smspace.train.engine import build
    from smspace.train.ensemble import Stacked

    cfgs = [config("MEM", 11, steps=20), config("MME", 13, steps=20)]
    lone = [build(replace(c, encoder_layers=[150, 100, 50]), 3, 4, torch.device("cpu"))[0] for c in cfgs]
    stacked = Stacked(lone)
    for r, model in enumerate(lone):
        assert list(stacked.run_state(r)) == list(model.state_dict())  # the lone model's own format
        for name, tensor in stacked.run_state(r).items():
            assert torch.equal(tensor, model.state_dict()[name]), name
    twice = []
    for attempt in ("a", "b"):
        runs = [RunDir.create(tmp_path / f"{attempt}{i}", c, False) for i, c in enumerate(cfgs)]
        train_ensemble(runs, progress=False)
        twice.append(runs)
    for a, b in zip(*twice, strict=True):
        ma, mb = a.view.metrics(), b.view.metrics()
        for row in (*ma, *mb):
            row.pop("elapsed_s")
        assert json.dumps(ma) == json.dumps(mb)
        for name, tensor in checkpoint(a)["model"].items():
            assert torch.equal(tensor, checkpoint(b)["model"][name]), name


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
    folders = sorted(p for p in out.iterdir() if p.is_dir())
    assert json.loads((out / "study.json").read_text())["terms"]["steps"] == 40
    assert [f.name for f in folders] == [f"grid-seed{w}-{m}-nh3-seed{w}" for w in (5, 6) for m in ("MEM", "MM", "MME")]
    for folder in folders:
        run = RunDir.open(folder)
        assert [r["step"] for r in run.view.metrics()] == [0, 20, 40] and run.view.status().state == "finished"
        assert run.view.embeddings(40)[0].shape == (125, 3)
    before = (folders[0] / "checkpoint.pt").read_bytes()
    assert smtrain(*args).exit_code == 0  # finished runs are left alone
    assert (folders[0] / "checkpoint.pt").read_bytes() == before
    extended = smtrain(*args[:-6], "--steps", 60, "--eval-every", 20, "--lake", lake, "--out", out)
    assert extended.exit_code == 0, extended.output
    assert all(RunView.open(f).metrics()[-1]["step"] == 60 for f in folders)
    # a sweep run is an ordinary run folder: fit --resume continues it, view and report read it
    resumed = smtrain("fit", "--resume", folders[1], "--steps", 80)
    assert resumed.exit_code == 0, resumed.output
    assert json.loads(resumed.output.strip().splitlines()[-1])["step"] == 80
    refused = smtrain(*args[:-6], "--steps", 60, "--batch-size", 50, "--lake", lake, "--out", out)
    assert refused.exit_code == 2 and "batch_size" in refused.output

    report = tmp_path / "report"
    result = smtrain("report", *folders, "--out", report)
    assert result.exit_code == 0, result.output
    # folders[1] was extended to 80 steps: another study, never averaged with the 60-step runs
    assert "2 studies, kept apart" in result.stderr and "they differ in steps" in result.stderr
    for name in (
        "grid-nh3-steps60_curves.png",
        "grid-nh3-steps60_projection_MEM.png",
        "grid-nh3-steps60_projection_MM.png",
        "grid-nh3-steps60_projection_MME.png",
        "grid-nh3-steps80_curves.png",
        "final.csv",
        "final.md",
        "runs.csv",
    ):
        assert (report / name).stat().st_size > 100, name
    with open(report / "final.csv") as fh:
        rows = [(r["study"], r["mode"], r["runs"], r["step"]) for r in csv.DictReader(fh)]
    assert rows == [
        ("grid-nh3-steps60", "MEM", "2", "60"),
        ("grid-nh3-steps60", "MM", "1", "60"),
        ("grid-nh3-steps60", "MME", "2", "60"),
        ("grid-nh3-steps80", "MM", "1", "80"),
    ]
    with open(report / "final.csv") as fh:
        first = next(csv.DictReader(fh))
    mem = [RunView.open(f).metrics()[-1]["d_metric"] for f in folders if "-MEM-" in f.name]
    assert float(first["d_metric_mean"]) == pytest.approx(np.mean(mem))
    assert float(first["d_metric_std"]) == pytest.approx(np.std(mem, ddof=1))  # the leaderboard's spread too
    assert "| grid-nh3-steps60 | grid | 3 | MME | 2 | 60 |" in (report / "final.md").read_text()


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
    h, p = run.view.embeddings(10)
    assert h.shape == (15625, 25) and p.shape == (15625, 2)
    state = torch.load(run.view.local_path / "checkpoint.pt", weights_only=True)["model"]
    assert state["encoder.0.weight"].shape == (6, 500)  # the paper's larger encoder for six motors (in, out)
    assert np.isfinite(run.view.metrics()[-1]["d_metric"])


@pytest.mark.slow
@pytest.mark.numerical
def test_a_run_does_not_depend_on_how_a_sweep_groups_or_places_it(tmp_path):
    """The same 6-run sweep as one ensemble here, as 3+3 on two processes, and as 1×6 Ray tasks."""
    import os
    import subprocess

    from tests.conftest import BIN

    lake = tmp_path / "lake"
    base = ["sweep", "--setup", "grid", "--worlds", 2, "--seed", 5, "--transitions", 2500, "--steps", 30]
    base += ["--eval-every", 10, "--lake", lake]
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
    names = sorted(p.name for p in (tmp_path / "six").iterdir() if p.is_dir())
    assert len(names) == 6
    for name in names:
        ref = torch.load(tmp_path / "six" / name / "checkpoint.pt", weights_only=True)
        for grouping in ("three", "one"):
            other = torch.load(tmp_path / grouping / name / "checkpoint.pt", weights_only=True)
            assert other["step"] == ref["step"] == 30
            mode = name.split("-")[2]  # grid-seed5-MEM-nh3-seed5
            assert_same_weights(ref["model"], other["model"], mode)  # tests/numerics.py: what is promised
            a, b = RunView(tmp_path / "six" / name).metrics(), RunView(tmp_path / grouping / name).metrics()
            assert_same_trajectory(a, b, mode)


def test_report_keeps_studies_apart_and_projects_wide_h(tmp_path):
    """Runs of two N_h are two studies: separate curves and rows, never one mean; h of N_h > 3 is
    drawn as its first three principal components."""
    from smspace.train.report import first_three

    runs = []
    for n_h in (3, 5):
        for mode in ("MEM", "MM"):
            cfg = replace(config(mode, 7, steps=20), n_h=n_h, eval_every=10)
            run = RunDir.create(tmp_path / f"{mode}-nh{n_h}", cfg, False)
            fit(cfg, run)
            runs.append(run.view.local_path)
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


def final_rows(report_dir) -> list[dict]:
    with open(report_dir / "final.csv") as fh:
        return list(csv.DictReader(fh))


def test_report_never_averages_values_of_different_steps(tmp_path):
    """One run of 40 steps evaluated every 10 and one of 80 every 20, on one dataset: before, the
    table paired the first run's step 40 with the second's step 80 and the curves put the second
    run's step 20 at step 10."""
    a, b = RunDir.create(tmp_path / "a", config("MM", 1, 40, 10), False), None
    fit(a.view.config, a)
    b = RunDir.create(tmp_path / "b", config("MM", 2, 80, 20), False)
    fit(b.view.config, b)
    result = smtrain("report", a.view.local_path, b.view.local_path, "--out", tmp_path / "report")
    assert result.exit_code == 0, result.output
    assert "they differ in eval_every, lr_decay_steps, steps" in result.stderr
    rows = {r["study"]: r for r in final_rows(tmp_path / "report")}
    assert set(rows) == {
        "grid-nh3-eval_every10-lr_decay_steps32-steps40",
        "grid-nh3-eval_every20-lr_decay_steps64-steps80",
    }
    for run, study in (
        (a, "grid-nh3-eval_every10-lr_decay_steps32-steps40"),
        (b, "grid-nh3-eval_every20-lr_decay_steps64-steps80"),
    ):
        last = run.view.metrics()[-1]
        assert (rows[study]["runs"], int(rows[study]["step"])) == ("1", last["step"])
        assert float(rows[study]["eval_loss_mean"]) == last["eval_loss"]


def test_report_of_runs_in_progress_compares_them_at_one_step(tmp_path):
    """Two runs of one study, one stopped at step 40 of 60: both are reported at step 40, each
    with its own value at step 40 (not the other's last row)."""
    runs = []
    for seed in (3, 4):
        run = RunDir.create(tmp_path / f"r{seed}", config("MME", seed, 60, 20), False)
        fit(run.view.config, run)
        runs.append(run)
    runs[1].write_metrics(runs[1].view.metrics()[:3])  # steps 0, 20, 40: as if still training
    result = smtrain("report", *(r.view.local_path for r in runs), "--out", tmp_path / "report")
    assert result.exit_code == 0, result.output
    assert "shown up to step 40, the last every run reached (1 run(s) are further along)" in result.stderr
    (row,) = final_rows(tmp_path / "report")
    at_40 = [next(m for m in r.view.metrics() if m["step"] == 40)["d_metric"] for r in runs]
    assert int(row["step"]) == 40 and float(row["d_metric_mean"]) == pytest.approx(np.mean(at_40))


def test_report_refuses_the_same_run_twice(tmp_path):
    run = RunDir.create(tmp_path / "a", config("MM", 1, 20, 10), False)
    fit(run.view.config, run)
    import shutil

    shutil.copytree(run.view.local_path, tmp_path / "copy")
    result = smtrain("report", run.view.local_path, tmp_path / "copy", "--out", tmp_path / "report")
    assert result.exit_code == 2 and "are the same run" in result.output


@pytest.mark.numerical
@pytest.mark.parametrize("max_ensemble", [3, 1])
def test_a_sweep_killed_between_the_checkpoints_of_one_ensemble_resumes_bit_identical(
    tmp_path, monkeypatch, max_ensemble
):
    """A kill between the checkpoint writes of one evaluation left one run at step 30 and the
    others at 20; the re-run regrouped them by step and the runs drifted apart (0.018 in weights).
    Now the recorded ensemble resumes from the step all reached, whatever --max-ensemble says."""
    lake = tmp_path / "lake"
    args = ["sweep", "--setup", "grid", "--worlds", 1, "--seed", 2, "--transitions", 3000, "--steps", 60]
    args += ["--eval-every", 10, "--lake", lake, "--workers", 1, "--gen-workers", 1]
    assert smtrain(*args, "--out", tmp_path / "clean", "--max-ensemble", 3).exit_code == 0
    saved = []
    original = RunDir.save_checkpoint

    def killed_at_30(self, state, keep_previous=False):
        if state["step"] == 30 and saved:
            raise KeyboardInterrupt  # the first run's checkpoint of step 30 is written, not the others'
        original(self, state, keep_previous)
        if state["step"] == 30:
            saved.append(self.name)

    with monkeypatch.context() as patched:
        patched.setattr(RunDir, "save_checkpoint", killed_at_30)
        assert smtrain(*args, "--out", tmp_path / "killed", "--max-ensemble", 3).exit_code == 130
    steps = sorted(RunView.open(p).checkpoint_step() for p in (tmp_path / "killed").iterdir() if p.is_dir())
    assert steps == [20, 20, 30]
    again = smtrain(*args, "--out", tmp_path / "killed", "--max-ensemble", max_ensemble)
    assert again.exit_code == 0, again.output
    for name in sorted(p.name for p in (tmp_path / "clean").iterdir() if p.is_dir()):
        a, b = RunDir.open(tmp_path / "clean" / name), RunDir.open(tmp_path / "killed" / name)
        ma, mb = a.view.metrics(), b.view.metrics()
        for row in (*ma, *mb):
            row.pop("elapsed_s")
        assert json.dumps(ma) == json.dumps(mb), name  # bit for bit, every step once
        ca, cb = checkpoint(a), checkpoint(b)
        assert all(torch.equal(ca["model"][k], cb["model"][k]) for k in ca["model"]), name


@pytest.mark.slow
def test_a_killed_sweep_worker_is_one_line_and_the_same_command_resumes(tmp_path):
    """kill -9 of one worker: a 43-line BrokenProcessPool traceback and a leaked-semaphore warning,
    the runs left "running" (and a spawn pool may even wait forever: CPython 3.11)."""
    import os
    import signal
    import subprocess

    import psutil

    from tests.conftest import BIN

    proc, out, args = _sweep_with_checkpoints(tmp_path, steps=400)
    workers = [p for p in psutil.Process(proc.pid).children() if _trains(p, out)]
    os.kill(workers[0].pid, signal.SIGKILL)
    _, stderr = proc.communicate(timeout=60)
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    # a busy machine may print the study's progress line first: one error line, last, and nothing else
    assert proc.returncode == 1 and all(ln.startswith("study: ") for ln in lines[:-1]), stderr
    assert lines[-1] == (
        f"smtrain: error: worker process {workers[0].pid} was killed by SIGKILL; "
        "the runs keep their last checkpoints: the same command resumes them"
    )
    states = {RunView.open(p).status().state for p in out.iterdir() if p.is_dir()}
    assert states <= {"failed", "finished"} and "failed" in states
    again = subprocess.run([str(BIN / "smtrain"), *map(str, args)], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert {RunView.open(p).status().state for p in out.iterdir() if p.is_dir()} == {"finished"}


def test_a_killed_progress_queue_does_not_stop_a_sweep(tmp_path):
    """The queue the workers report progress on lives in a manager process: killing it ends the
    progress lines, never the training."""
    import os
    import signal

    import psutil

    proc, out, _ = _sweep_with_checkpoints(tmp_path, steps=600)
    children = [p for p in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(p.cmdline())]
    managers = [p for p in children if not _trains(p, out)]
    assert len(managers) == 1 and len(children) == 3
    os.kill(managers[0].pid, signal.SIGKILL)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert {RunView.open(p).status().state for p in out.iterdir() if p.is_dir()} == {"finished"}


@pytest.mark.slow
def test_nothing_outlives_a_sweep_killed_with_sigkill(tmp_path):
    """kill -9 of the driver: its pool workers, its progress queue's manager process and its
    resource tracker all end (the manager lived on, parented to init, minutes later)."""
    import os
    import signal

    import psutil

    proc, _, _ = _sweep_with_checkpoints(tmp_path, steps=3000)
    started = psutil.Process(proc.pid).children(recursive=True)
    kinds = [" ".join(p.cmdline()) for p in started]
    assert sum("spawn_main" in k for k in kinds) == 3 and any("resource_tracker import main" in k for k in kinds), kinds
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    _, alive = psutil.wait_procs(started, timeout=20)
    assert not alive, [(p.pid, " ".join(p.cmdline())) for p in alive]


@pytest.mark.slow
def test_a_killed_resource_tracker_leaves_a_sweep_quiet(tmp_path):
    """kill -9 of the sweep's resource tracker: the sweep finishes, exit 0, with no warning and no
    KeyError traceback (five were printed by the tracker started in its place)."""
    import os
    import signal

    import psutil

    proc, out, _ = _sweep_with_checkpoints(tmp_path, steps=300)
    children = psutil.Process(proc.pid).children()
    (tracker,) = [p for p in children if "resource_tracker import main" in " ".join(p.cmdline())]
    os.kill(tracker.pid, signal.SIGKILL)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "KeyError" not in stderr and "resource_tracker" not in stderr, stderr
    assert {RunView.open(p).status().state for p in out.iterdir() if p.is_dir()} == {"finished"}


@pytest.mark.slow
def test_an_interrupted_sweep_says_interrupted_as_a_lone_fit_does(tmp_path):
    """SIGTERM to a sweep: its runs were left "running", shown "stale" ("its process is gone");
    now each says "interrupted", as a lone fit does, and the same command resumes them."""
    import signal

    proc, out, _ = _sweep_with_checkpoints(tmp_path, steps=3000)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    runs = [RunDir.open(p) for p in sorted(out.iterdir()) if p.is_dir()]
    statuses = [run.view.status() for run in runs]
    assert {s.state for s in statuses} == {"interrupted"}, statuses
    assert all("the same sweep resumes it" in s.message for s in statuses), statuses
    assert [s.step for s in statuses] == [run.view.checkpoint_step() for run in runs]  # where each resumes
    listed = smtrain("ls", "--runs", out)
    assert listed.exit_code == 0 and "interrupted" in listed.output and "stale" not in listed.output, listed.output


def test_a_sweep_stopped_before_a_runs_first_status_marks_it_all_the_same(tmp_path):
    """Under load, SIGTERM fell between a run's first checkpoint and the status written after it:
    the run stayed "created" beside its checkpoint while its siblings said "interrupted". A run
    with no checkpoint never started, and says so."""
    from smspace.study.sweep import _mark_stopped

    started, untouched = (RunDir.create(tmp_path / name, config("MM", 1), overwrite=False) for name in "ab")
    started.save_checkpoint({"step": 0})
    _mark_stopped([started, untouched], "interrupted", "interrupted; the same sweep resumes it")
    status = started.view.status()
    assert (status.state, status.step) == ("interrupted", 0), status
    assert untouched.view.status().state == "created"


def _sweep_with_checkpoints(tmp_path, steps: int):
    """A two-worker grid sweep started as a process, once each of its 6 runs has a checkpoint."""
    import subprocess
    import time

    from tests.conftest import BIN

    out, lake = tmp_path / "runs", tmp_path / "lake"
    args = ["sweep", "--setup", "grid", "--worlds", 2, "--transitions", 3000, "--steps", steps, "--eval-every", 50]
    args += ["--lake", lake, "--out", out, "--workers", 2, "--gen-workers", 1]
    proc = subprocess.Popen(
        [str(BIN / "smtrain"), *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while len(list(out.glob("*/checkpoint.pt"))) < 6:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    return proc, out, args


def _trains(process, out) -> bool:
    """A pool worker holds its runs' locks; the progress queue's manager process holds none."""
    return "spawn_main" in " ".join(process.cmdline()) and any(str(out) in f.path for f in process.open_files())


@pytest.mark.parametrize("field", ["eval_transitions", "shuffle_window", "batch_size", "compile"])
def test_runs_of_one_ensemble_share_every_study_term_new_fields_included(tmp_path, field):
    """What an ensemble checks is what a study shares (train/terms.py), not a list of its own:
    eval_transitions and shuffle_window are terms no flag sets, and are refused all the same."""
    first = config("MM", 1)
    value = getattr(first, field)
    changed = {"compile": "on" if value == "off" else "off"}.get(
        field, (not value) if isinstance(value, bool) else value * 2
    )
    other = replace(config("MM", 2), **{field: changed})
    runs = [RunDir.create(tmp_path / f"r{i}", cfg, False) for i, cfg in enumerate((first, other))]
    with pytest.raises(SmspaceError, match=f"runs of one ensemble must share {field}"):
        train_ensemble(runs, progress=False)
    assert all(run.view.checkpoint_step() == 0 for run in runs)


def test_a_write_that_fails_behind_the_steps_stops_the_ensemble_and_is_recorded(tmp_path, monkeypatch):
    """An ensemble's run folders are written by a thread while the next steps train: a write that
    fails there (a full disk) still stops the training with its own line, marks every run, leaves
    each checkpoint at or behind its files, and the same runs resume to the end."""
    import threading

    cfgs = [config("MEM", 11), config("MM", 12)]
    runs = [RunDir.create(tmp_path / f"r{i}", c, False) for i, c in enumerate(cfgs)]
    original = RunDir.write_metrics

    def full_disk(self, rows):
        if rows[-1]["step"] == 20 and self.name == "r1":
            raise SmspaceError(f"cannot write {self.url}/metrics.parquet: No space left on device")
        original(self, rows)

    with monkeypatch.context() as patched:
        patched.setattr(RunDir, "write_metrics", full_disk)
        with pytest.raises(SmspaceError, match="No space left on device"):
            train_ensemble(runs, progress=False)
    assert not [t for t in threading.enumerate() if t.name.startswith("smspace-run-writes")]
    assert [run.view.checkpoint_step() for run in runs] == [20, 10]
    for run in runs:
        status = RunView.open(run.view.local_path).status()
        assert status.state == "failed" and "No space left on device" in status.message, status
    assert max(row["step"] for row in runs[1].view.metrics()) == 10
    again = [RunDir.open(run.view.local_path) for run in runs]
    train_ensemble(again, resume=True, progress=False)
    for run in again:
        assert [row["step"] for row in run.view.metrics()] == list(range(0, 61, 10))
        assert run.view.status().state == "finished"
