"""Studies as files (study/file.py, study/runner.py), and progress in every log (common/progress.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from .conftest import ROOT, run_cmd

TINY = """
[study]
setup = "grid"
modes = ["MM"]
worlds = 1
seed = 5
transitions = 3000

[train]
steps = {steps}
eval_every = 100
batch_size = 50
{extra}

[grid]
n_h = [3, 4]

[run]
workers = 2
"""


def write_study(path: Path, steps: int = 200, extra: str = "") -> Path:
    path.write_text(TINY.format(steps=steps, extra=extra))
    return path


def smtrain(*args, env: dict | None = None, timeout: float = 300):
    cmd = [str(a) for a in args]
    return run_cmd("smtrain", *cmd, timeout=timeout, env=env or {})


def test_every_study_file_of_the_repository_is_valid():
    from smspace.study.file import load_study

    files = sorted((ROOT / "studies").rglob("*.toml"))
    assert len(files) >= 6
    for path in files:
        study = load_study(path)
        assert study.combinations()
    text = (ROOT / "scripts" / "reproduce.sh").read_text()
    for name in ("grid", "arm", "grid-nh25", "grid6", "arm-more", "arm6"):
        assert (ROOT / "studies" / f"{name}.toml").exists()
    assert 'sweep "studies/$1.toml"' in text and "--steps" not in text  # the studies' terms live in the files


@pytest.mark.parametrize(
    ("section", "problem", "named"),
    [
        ("[train]\nn_h = 'three'", "expected an integer", "train.n_h"),
        ("[train]\nlr_start = -1", "finite positive", "train.lr_start"),
        ("[train]\nlayers = [3]", "unknown training field", "train.layers"),
        ("[train]\nseed = 3", "set study.seed", "train.seed"),
        ("[grid]\nn_h = []", "non-empty list", "grid.n_h"),
        ("[grid]\nn_h = [3, 3]", "names a value twice", "grid.n_h"),
        ("[run]\nexecutor = 'slurm'", "expected one of local, ray", "run.executor"),
        ("[runs]\nworkers = 2", "unknown section", "runs"),
    ],
)
def test_a_bad_study_file_is_one_line_naming_the_key(tmp_path, section, problem, named):
    from smspace.common.errors import SmspaceError
    from smspace.study.file import load_study

    path = tmp_path / "bad.toml"
    path.write_text(f'[study]\nsetup = "grid"\n{section}\n')
    with pytest.raises(SmspaceError) as err:
        load_study(path)
    line = str(err.value)
    assert "\n" not in line and str(path) in line and named in line and problem in line


def test_a_bad_study_file_exits_2_and_writes_nothing(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[study]\nsetup = "grid"\nmodes = ["MX"]\n')
    result = smtrain("sweep", path, "--lake", tmp_path / "lake", "--out", tmp_path / "out")
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "study.modes" in result.stderr and "'MX'" in result.stderr
    assert not (tmp_path / "lake").exists() and not (tmp_path / "out").exists()


def test_flags_that_the_study_file_holds_are_refused(tmp_path):
    path = write_study(tmp_path / "s.toml")
    result = smtrain("sweep", path, "--steps", 5, "--worlds", 2, "--out", tmp_path / "out")
    assert result.returncode == 2
    assert "--worlds, --steps: set in the study file" in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_dry_run_budgets_the_study_and_writes_nothing(tmp_path):
    path = write_study(tmp_path / "s.toml")
    result = smtrain("sweep", path, "--dry-run", "--lake", tmp_path / "lake", "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "1 to generate (3000 transitions" in out and "transitions/s per worker, both measured now" in out
    assert "n_h=3: 1 runs, 200 run-steps to train" in out and "n_h=4: 1 runs" in out
    assert "runs: 2 new, 0 to resume, 0 finished" in out and "disk: about" in out and "time: about" in out
    assert not (tmp_path / "lake").exists() and not (tmp_path / "out").exists()


def test_a_study_file_runs_its_grid_records_itself_and_says_what_changed(tmp_path):
    path = write_study(tmp_path / "s.toml")
    lake, out = tmp_path / "lake", tmp_path / "out"
    first = smtrain("sweep", path, "--lake", lake, "--out", out)
    assert first.returncode == 0, first.stderr
    for n_h in (3, 4):
        run = out / f"n_h={n_h}" / f"grid-seed5-MM-nh{n_h}-seed5"
        cfg = json.loads((run / "config.json").read_text())
        assert cfg["n_h"] == n_h and cfg["steps"] == 200 and cfg["batch_size"] == 50
        assert json.loads((run / "status.json").read_text())["state"] == "finished"
    recorded = json.loads((out / "study-file.json").read_text())
    assert recorded["grid"] == {"n_h": [3, 4]} and recorded["train"]["steps"] == 200
    assert (out / "study-file.toml").read_text() == path.read_text()

    write_study(path, steps=300)  # an extension: said, and done on the recorded schedule
    second = smtrain("sweep", path, "--lake", lake, "--out", out)
    assert second.returncode == 0, second.stderr
    assert "changed since it last ran: train.steps 200 -> 300" in second.stderr
    assert "extending the study" in second.stderr
    cfg = json.loads((out / "n_h=3" / "grid-seed5-MM-nh3-seed5" / "config.json").read_text())
    assert cfg["steps"] == 300 and cfg["lr_decay_steps"] == 160

    before = (out / "study-file.json").read_bytes()
    write_study(path, steps=300, extra="lr_start = 0.002")  # another study: refused, nothing written
    third = smtrain("sweep", path, "--lake", lake, "--out", out)
    assert third.returncode == 2
    assert "lr_start 0.001 (asked 0.002)" in third.stderr and third.stderr.strip().count("\n") == 0
    assert (out / "study-file.json").read_bytes() == before


def test_logs_get_progress_lines_when_not_on_a_terminal(tmp_path, grid_lake):
    """fit and a two-worker sweep, written to a file (pipes here): plain lines every interval."""
    env = {"SMSPACE_PROGRESS_EVERY": "0.2"}
    fit = smtrain(
        "fit", "grid-seed3-MM", "--lake", grid_lake, "--out", tmp_path / "run", "--steps", 600, "--eval-every", 200,
        env=env,
    )  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    lines = [ln for ln in fit.stderr.splitlines() if ln.startswith("training: ")]
    assert len(lines) >= 2, fit.stderr
    assert all("steps/s" in ln and "ETA" in ln for ln in lines)
    assert lines[-1].startswith("training: 600/600 steps (100%)") and "D_topo" in lines[-1] and "loss" in lines[-1]

    sweep = smtrain(
        "sweep", write_study(tmp_path / "s.toml", steps=400), "--lake", tmp_path / "lake", "--out", tmp_path / "out",
        env=env,
    )  # fmt: skip
    assert sweep.returncode == 0, sweep.stderr
    study = [ln for ln in sweep.stderr.splitlines() if ln.startswith("study: ")]
    assert len(study) >= 2 and "run-steps/s" in study[-1] and "ETA" in study[-1]
    assert study[-1].startswith("study: 800/800 run-steps (100%)") and "runs 2/2 finished, 0 running" in study[-1]
    assert any(ln.startswith("generating: 3000/3000 transitions") for ln in sweep.stderr.splitlines())


def test_a_dry_run_plans_what_the_sweep_will_do_with_the_recorded_ensembles(tmp_path):
    """The dry run and the sweep plan with one function: groups study.json recorded are kept
    whatever [run] says now, and a run killed before its first checkpoint is created afresh (new),
    not resumed."""

    def study(steps: int, size: int) -> str:  # three worlds, no grid, one worker
        text = TINY.format(steps=steps, extra="").replace("worlds = 1", "worlds = 3")
        return text.replace("[grid]\nn_h = [3, 4]\n", "").replace("workers = 2", f"workers = 1\nmax_ensemble = {size}")

    path, lake, out = tmp_path / "s.toml", tmp_path / "lake", tmp_path / "out"
    path.write_text(study(200, 1))
    assert smtrain("sweep", path, "--lake", lake, "--out", out).returncode == 0
    assert json.loads((out / "study.json").read_text())["ensembles"] == [
        [f"grid-seed{w}-MM-nh3-seed{w}"] for w in (5, 6, 7)
    ]
    (out / "grid-seed7-MM-nh3-seed7" / "checkpoint.pt").unlink()  # as if killed before its first checkpoint
    path.write_text(study(300, 3))
    dry = smtrain("sweep", path, "--dry-run", "--lake", lake, "--out", out)
    assert dry.returncode == 0, dry.stderr
    assert "in 3 ensemble(s) of 1 (" in dry.stdout  # the recorded groups, not one group of 3
    assert "runs: 1 new, 2 to resume, 0 finished" in dry.stdout
    assert "3 runs, 500 run-steps to train" in dry.stdout  # 2 x 100 resumed + 300 afresh


def test_flags_a_study_file_and_the_api_are_one_request_trained_alike(tmp_path):
    """Every way of starting runs builds one study request for one runner (study/runner.py): the
    same study given by flags, by a file and by smspace.define_study trains the same weights; only a
    file and the API have a source to record."""
    import torch

    import smspace
    from smspace.train.run_dir import RunDir

    lake = tmp_path / "lake"
    train = ["--steps", 100, "--eval-every", 50, "--batch-size", 50, "--nh", 3]
    dataset = ["--setup", "grid", "--modes", "MM", "--worlds", 1, "--seed", 5, "--transitions", 3000]
    flags = smtrain("sweep", *dataset, *train, "--workers", 1, "--lake", lake, "--out", tmp_path / "flags")
    assert flags.returncode == 0, flags.stderr
    file = tmp_path / "s.toml"
    file.write_text(TINY.format(steps=100, extra="eval_every = 50\nn_h = 3").replace("eval_every = 100\n", "")
                    .replace("[grid]\nn_h = [3, 4]\n", "").replace("workers = 2", "workers = 1"))  # fmt: skip
    from_file = smtrain("sweep", file, "--lake", lake, "--out", tmp_path / "file")
    assert from_file.returncode == 0, from_file.stderr
    study = smspace.define_study(
        {"setup": "grid", "modes": ["MM"], "worlds": 1, "seed": 5, "transitions": 3000},
        train={"steps": 100, "eval_every": 50, "batch_size": 50, "n_h": 3},
    )
    smspace.run_study(study, out=tmp_path / "api", lake=lake, workers=1)

    name = "grid-seed5-MM-nh3-seed5"
    weights = [RunDir.open(tmp_path / way / name).load_checkpoint()["model"] for way in ("flags", "file", "api")]
    for other in weights[1:]:
        assert weights[0].keys() == other.keys()
        assert all(torch.equal(weights[0][k], other[k]) for k in weights[0])
    assert not (tmp_path / "flags" / "study-file.toml").exists()  # flags have no file to record
    assert (tmp_path / "file" / "study-file.toml").read_bytes() == file.read_bytes()
    recorded = (tmp_path / "api" / "study-file.toml").read_text()
    assert "n_h = 3" in recorded and json.loads((tmp_path / "api" / "study-file.json").read_text())["seed"] == 5
    with pytest.raises(smspace.SmspaceError, match=r"train\.steps: "):
        smspace.define_study({"setup": "grid"}, train={"steps": -1})
