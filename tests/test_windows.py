"""`smtrain fit --window K` (issue 44): a model that reads windows of K consecutive steps of a walk
(the path integrator, bench/entries.py) trains on them alone, stacked and on two ranks alike,
resumes to the same bytes, and every window a run cannot have is refused before anything is written."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from smspace.train.config import TrainConfig
from smspace.train.fit import fit, train_ensemble
from smspace.train.run_dir import RunDir

from .conftest import SAMPLES, StopAt, failed_in_one_line, run_cmd, short_fit, smgen, smtrain, weights
from .numerics import assert_same_weights

WALK = ["--exploration", "walk", "--walk-length", "20", "--transitions", "2000", "--shard-size", "1000"]


@pytest.fixture(scope="module")
def walks(tmp_path_factory) -> Path:
    lake = tmp_path_factory.mktemp("window_lake")
    for seed in (2, 3):
        result = smgen("generate", "--setup", "grid", "--mode", "MME", "--seed", seed, "--lake", lake, *WALK)
        assert result.exit_code == 0, result.output
    return lake


def config(lake: Path, seed: int = 2, window: int = 5, model: str = "path-integrator") -> TrainConfig:
    ds = lake / f"grid-seed{seed}-MME-walk"
    return TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=40, eval_every=20, seed=seed, model=model,
                       window=window, batch_size=32)  # fmt: skip


def test_a_path_integrator_trains_on_windows_of_a_walk(walks, tmp_path):
    out = tmp_path / "run"
    done = short_fit("grid-seed2-MME-walk", walks, out, "--model", "path-integrator", "--window", 5)
    assert done.returncode == 0, done.stderr
    run = RunDir.open(out)
    recorded = json.loads((out / "config.json").read_text())
    assert recorded["window"] == 5 and run.view.config.window == 5
    rows = run.view.metrics()
    assert run.view.status().state == "finished" and rows[-1]["train_loss"] < rows[1]["train_loss"], rows


def test_windows_change_what_is_trained(walks, tmp_path):
    """Windows of 5 and of 1 give the same model other batches, hence other weights: the window
    reaches the objective (a window ignored would leave them equal)."""
    runs = {}
    for window in (1, 5):
        runs[window] = RunDir.create(tmp_path / f"w{window}", config(walks, window=window), False)
        fit(config(walks, window=window), runs[window])
    a, b = weights(runs[1]), weights(runs[5])
    assert any(not torch.equal(a[k], b[k]) for k in a)


def test_a_windowed_run_is_the_same_alone_and_stacked(walks, tmp_path):
    cfgs = [config(walks, seed=2), config(walks, seed=3)]
    alone = RunDir.create(tmp_path / "alone", cfgs[0], False)
    fit(cfgs[0], alone)
    members = [RunDir.create(tmp_path / f"member{i}", c, False) for i, c in enumerate(cfgs)]
    train_ensemble(members, progress=False)
    assert_same_weights(weights(alone), weights(members[0]), "MME")


def test_a_resumed_windowed_run_ends_bit_identical_to_one_never_stopped(walks, tmp_path):
    straight = RunDir.create(tmp_path / "straight", config(walks), False)
    fit(config(walks), straight)
    stopped = RunDir.create(tmp_path / "stopped", config(walks), False)
    with pytest.raises(KeyboardInterrupt):
        fit(config(walks), stopped, sinks=[StopAt(20)])
    fit(config(walks), RunDir.open(stopped.view.local_path), resume=True)
    a, b = weights(straight), weights(RunDir.open(stopped.view.local_path))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_a_windowed_run_trains_on_two_ranks(walks, tmp_path):
    """Each rank reads its own share of the windows; DDP averages the objective's gradients, or
    the ranks' weights would drift apart (every evaluation compares them)."""
    out = tmp_path / "run"
    args = ["smtrain", "fit", walks / "grid-seed2-MME-walk", "--model", "path-integrator", "--window", 4]
    done = run_cmd(*args, "--nproc", 2, "--steps", 40, "--eval-every", 20, "--out", out, timeout=300)
    assert done.returncode == 0, done.stderr
    run = RunDir.open(out)
    assert run.view.config.world_size == 2 and run.view.config.window == 4
    assert run.view.status().state == "finished"


def test_a_run_of_single_transitions_records_no_window(tmp_path):
    """config.json keeps the bytes (and the terms) it had before windows existed."""
    out = tmp_path / "run"
    assert short_fit("grid-seed0-MM", SAMPLES, out).returncode == 0
    assert "window" not in json.loads((out / "config.json").read_text())
    # the path integrator reads windows of one step of independent transitions too
    one = tmp_path / "one"
    assert short_fit("grid-seed0-MM", SAMPLES, one, "--model", "path-integrator").returncode == 0


@pytest.mark.parametrize(
    ("dataset", "extra", "named"),
    [
        ("grid-seed2-MME-walk", ["--window", 5],
         "model 'sensorimotor' reads single transitions; --window 5 needs a model"),
        ("grid-seed0-MM", ["--model", "path-integrator", "--window", 5],
         "--window 5: grid-seed0-MM is independent transitions: windows of 5 steps need walks"),
        ("grid-seed2-MME-walk", ["--model", "path-integrator", "--window", 21],
         "--window 21: windows of 21 steps do not fit in grid-seed2-MME-walk's episodes of 20"),
        ("grid-seed2-MME-walk", ["--model", "path-integrator", "--window", 0], "window"),
    ],
)  # fmt: skip
def test_a_window_a_run_cannot_have_is_refused_before_anything_is_written(walks, tmp_path, dataset, extra, named):
    lake = SAMPLES if dataset == "grid-seed0-MM" else walks
    out = tmp_path / "run"
    result = smtrain("fit", dataset, "--lake", lake, "--out", out, "--steps", 10, *extra)
    failed_in_one_line(result)
    assert named in result.output and not out.exists(), result.output


WALK_STUDY = """
[study]
setup = "grid"
modes = ["MME"]
worlds = 2
seed = 2
transitions = 2000
{exploration}

[train]
model = "path-integrator"
steps = 40
eval_every = 20
batch_size = 32
{train}

[run]
workers = 1
"""


def walk_study(path: Path, exploration: str = 'exploration = "walk"\nwalk_length = 20', train: str = "window = 5"):
    path.write_text(WALK_STUDY.format(exploration=exploration, train=train))
    return path


def test_a_study_of_walks_trains_windows_as_lone_runs_would(tmp_path):
    """study.exploration = "walk": the study generates walks (the -walk datasets smgen would),
    trains its runs on windows stacked, each as `fit` alone would, and records the exploration as
    a term of its runs, so a study of transitions is refused in the same folder."""
    lake, out = tmp_path / "lake", tmp_path / "out"
    done = run_cmd("smtrain", "sweep", walk_study(tmp_path / "s.toml"), "--lake", lake, "--out", out, timeout=600)
    assert done.returncode == 0, done.stderr
    made = sorted(p.parent.name for p in lake.glob("*/manifest.json"))
    assert made == ["grid-seed2-MME-walk", "grid-seed3-MME-walk"]
    walk = ["--exploration", "walk", "--walk-length", 20, "--transitions", 2000]  # the study's words, as flags
    made = smgen("generate", "--setup", "grid", "--mode", "MME", "--seed", 2, "--lake", tmp_path / "own", *walk)
    assert made.exit_code == 0
    own = json.loads((tmp_path / "own/grid-seed2-MME-walk/manifest.json").read_text())
    study = json.loads((lake / "grid-seed2-MME-walk/manifest.json").read_text())
    assert own["config_hash"] == study["config_hash"]  # the very dataset smgen generates

    run = RunDir.open(out / "grid-seed2-MME-walk-nh3-seed2")
    cfg = run.view.config
    assert cfg.window == 5 and cfg.exploration == {"kind": "walk", "length": 20, "step": 1.0}
    assert run.view.status().state == "finished"
    alone = RunDir.create(tmp_path / "alone", replace(cfg, run_id="", sessions=[]), False)
    fit(replace(cfg, run_id="", sessions=[]), alone)
    assert_same_weights(weights(alone), weights(run), "MME")

    before = (out / "study-file.json").read_bytes()
    again = run_cmd("smtrain", "sweep", walk_study(tmp_path / "s.toml", "", "window = 1"), "--lake", lake,
                    "--out", out, timeout=300)  # fmt: skip
    failed_in_one_line(again)
    said = 'exploration {"kind": "walk", "length": 20, "step": 1.0} (asked null), window 5 (asked 1)'
    assert said in again.stderr
    assert (out / "study-file.json").read_bytes() == before


@pytest.mark.parametrize(
    ("exploration", "train", "named"),
    [
        ("walk_length = 20", "window = 1", 'study.walk_length: is for walks only (exploration "walk")'),
        ('exploration = "hop"', "window = 1", "study.exploration: 'hop' is not one of transitions, walk"),
        ('exploration = "walk"\nwalk_step = 9', "window = 1", "study.walk_step: 9 is not a number in (0, 4.0]"),
        ('exploration = "walk"\nwalk_length = 30', "window = 1", "must be multiples of the length"),
        ('exploration = "walk"\nwalk_length = 20', "window = 21", "window: 21 steps do not fit in the study's"),
        ("", "window = 5", 'windows need walks (study.exploration = "walk")'),
    ],
)
def test_a_walk_study_a_run_cannot_have_is_refused_before_anything_is_written(tmp_path, exploration, train, named):
    lake, out = tmp_path / "lake", tmp_path / "out"
    done = run_cmd("smtrain", "sweep", walk_study(tmp_path / "s.toml", exploration, train), "--lake", lake,
                   "--out", out, timeout=300)  # fmt: skip
    failed_in_one_line(done)
    assert named in done.stderr and not out.exists() and not lake.exists(), done.stderr


def test_walk_and_transition_runs_of_one_world_are_never_one_study(walks):
    """The exploration is a term (train/terms.py, rule 5): runs on a world's walks and on its
    transitions differ in it, so a report or a sweep folder never pools them."""
    from smspace.lake.dataset import Dataset
    from smspace.train.terms import terms

    plain, walk = TrainConfig(dataset=""), Dataset.open("grid-seed2-MME-walk", walks)
    on_walks = plain.for_dataset(walk.store, walk.manifest)
    sample = Dataset.open(str(SAMPLES / "grid-seed0-MME"))
    on_transitions = plain.for_dataset(sample.store, sample.manifest)
    assert terms(on_walks)["exploration"] == {"kind": "walk", "length": 20, "step": 1.0}
    assert "exploration" not in terms(on_transitions) and "exploration" not in on_transitions.to_dict()


def test_a_sweep_given_by_flags_generates_and_trains_walks(tmp_path):
    """`smtrain sweep --exploration walk …` is the study file's exploration keys as flags, the
    same flags (datagen/options.py) and checks as smgen generate's."""
    lake, out = tmp_path / "lake", tmp_path / "out"
    args = ["--setup", "grid", "--modes", "MME", "--worlds", 1, "--seed", 2, "--transitions", 2000, "--lake", lake]
    walk = ["--exploration", "walk", "--walk-length", 20, "--model", "path-integrator", "--window", 5]
    train = ["--steps", 20, "--eval-every", 20, "--batch-size", 32, "--out", out]
    done = run_cmd("smtrain", "sweep", *args, *walk, *train, timeout=300)
    assert done.returncode == 0, done.stderr
    cfg = RunDir.open(out / "grid-seed2-MME-walk-nh3-seed2").view.config
    assert cfg.window == 5 and cfg.exploration == {"kind": "walk", "length": 20, "step": 1.0}

    alone = smtrain("sweep", *args, "--walk-length", 20, *train[:-1], tmp_path / "other")
    failed_in_one_line(alone)
    assert '--walk-length: is for walks only (exploration "walk")' in alone.output
    beside = smtrain("sweep", walk_study(tmp_path / "s.toml"), "--exploration", "walk", "--out", tmp_path / "o")
    failed_in_one_line(beside)
    assert "--exploration: set in the study file" in beside.output
