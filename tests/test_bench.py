"""smspace-bench: its baselines (bench/entries.py), suites, runner and leaderboard."""

from __future__ import annotations

import itertools
import json
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch

from smspace.bench.run import check_task
from smspace.bench.suite import SUITES, get_suite
from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.metrics.probe import probe_r2
from smspace.train.config import TrainConfig
from smspace.train.engine import build
from smspace.train.fit import fit, train_ensemble
from smspace.train.run_dir import RunDir

from .conftest import SAMPLES, StopAt, run_cmd, weights
from .numerics import assert_same_weights

BASELINES = [
    "random-encoder",
    "motor-autoencoder",
    "contrastive",
    "beta-vae",
    "latent-forward",
    "displacement",
    "slow-features",
]


def config(model: str, seed: int = 3, mode: str = "MM", steps: int = 40) -> TrainConfig:
    ds = SAMPLES / f"grid-seed0-{mode}"
    return TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=steps, eval_every=20, seed=seed, model=model)


@pytest.mark.parametrize("model", BASELINES)
def test_a_baseline_trains_on_its_own_objective_alone_and_in_an_ensemble(tmp_path, model):
    """Each baseline trains its objective (its loss falls), the same alone as stacked in a sweep's
    ensemble, and leaves untrained what it must (the random encoder's encoder)."""
    cfgs = [config(model, seed=3), config(model, seed=4, mode="MME")]
    alone = RunDir.create(tmp_path / "alone", cfgs[0], False)
    fit(cfgs[0], alone)
    members = [RunDir.create(tmp_path / f"member{i}", c, False) for i, c in enumerate(cfgs)]
    train_ensemble(members, progress=False)
    assert_same_weights(weights(alone), weights(members[0]), "MM")
    rows = alone.view.metrics()
    assert rows[-1]["train_loss"] < rows[1]["train_loss"] or model == "random-encoder", rows
    manifest = Dataset.open(cfgs[0].dataset).manifest
    shape = manifest.n_motor, math.prod(manifest.sensor_shape)
    initial = build(alone.view.config, *shape, torch.device("cpu"))[0].state_dict()
    moved = {k for k, v in weights(alone).items() if not torch.equal(v, initial[k])}
    if model == "random-encoder":
        assert moved and not any(k.startswith("encoder") for k in moved), moved
    else:
        assert any(k.startswith("encoder") for k in moved), moved


def test_the_baselines_are_registered_as_plugins_are():
    from smspace.train.model import model_plugin

    for name in BASELINES:
        plugin = model_plugin(name)
        assert plugin is not None and plugin.distribution == "smspace" and len(plugin.code_sha256) == 16, plugin


def test_a_suites_later_versions_only_add_tasks():
    """What version N measured stays comparable in version N+1: every task is kept, unchanged."""
    for name, versions in SUITES.items():
        assert [s.version for s in versions] == list(range(1, len(versions) + 1)), name
        for before, after in itertools.pairwise(versions):
            assert set(before.tasks) <= set(after.tasks), f"{after.label} drops or changes a task of {before.label}"
            kept = {t.name: t.datasets_hash for t in before.tasks}
            assert all(kept.get(t.name, t.datasets_hash) == t.datasets_hash for t in after.tasks)
    assert len(SUITES["tiny"]) >= 2  # the rule is exercised


def test_the_datasets_a_suite_fixed_are_the_ones_generation_configures():
    """A change to generation's configs (a shard size, a default) changes a task's datasets: it
    must then be a new task in a new version, never the old one measured on other data."""
    for versions in SUITES.values():
        for suite in versions:
            for task in suite.tasks:
                check_task(suite, task)
    changed = replace(SUITES["tiny"][0].tasks[0], transitions=3001)
    with pytest.raises(SmspaceError, match="configures its datasets differently"):
        check_task(SUITES["tiny"][0], changed)


def test_suite_names_and_versions_are_checked():
    assert get_suite("tiny").version == len(SUITES["tiny"]) and get_suite("tiny@1").version == 1
    versions = f"versions 1..{len(SUITES['tiny'])}"
    for bad, said in [("nope", "unknown suite 'nope'"), ("tiny@0", versions), ("tiny@x", versions)]:
        with pytest.raises(SmspaceError, match=said):
            get_suite(bad)


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory):
    """The tiny suite run end to end by the command line: a model of another package (the plugin
    demo's `shallow`) and the non-learned `isomap`, then the leaderboard of both."""
    root = tmp_path_factory.mktemp("bench")
    args = ["smtrain", "bench", "tiny@1", "shallow", "isomap", "--lake", root / "lake", "--out", root / "out"]
    done = run_cmd(*args, "--workers", 1, timeout=600)
    assert done.returncode == 0, done.stderr
    board = run_cmd("smtrain", "leaderboard", root / "out", "--out", root / "board")
    assert board.returncode == 0, board.stderr
    return root, args


def test_a_plugin_entry_runs_the_tiny_suite_and_lands_on_the_leaderboard(tiny_bench):
    root, _ = tiny_bench
    record = json.loads((root / "out/tiny-v1/shallow/grid/bench.json").read_text())
    assert (
        record["suite"] == "tiny"
        and record["version"] == 1
        and record["task"] == get_suite("tiny@1").task("grid").protocol()
    )
    assert record["entry"]["plugin"]["distribution"] == "smspace-plugin-demo"
    assert [s["wall_s"] > 0 for s in record["sessions"]] == [True]
    board = json.loads((root / "board/leaderboard.json").read_text())
    cells = {(c["entry"], c["task"], c["mode"], c["score"]): c for c in board["cells"]}
    assert {(e, m) for e, _, m, _ in cells} == {(e, m) for e in ("shallow", "isomap") for m in ("MM", "MME")}
    for cell in cells.values():
        assert cell["worlds"] == [0, 1] and math.isfinite(cell["mean"]) and math.isfinite(cell["std"]), cell
    # the scores are those of the runs' own embeddings, measured again here (the probe's folds: the world's seed)
    run = RunDir.open(next(p for p in (root / "out/tiny-v1/shallow/grid").iterdir() if "-MM-" in p.name))
    h, p = run.view.embeddings(run.view.metrics()[-1]["step"])
    rows = json.loads((root / "out/tiny-v1/shallow/grid/scores.json").read_text())["rows"]
    expected = np.mean([r["probe_r2"] for r in rows if r["mode"] == "MM"])
    assert cells[("shallow", "grid", "MM", "probe_r2")]["mean"] == pytest.approx(expected)
    mine = next(r for r in rows if r["run"] == run.name)
    assert mine["probe_r2"] == pytest.approx(probe_r2(h, p, seed=mine["world"]), rel=1e-12)
    text = (root / "board/leaderboard.md").read_text()
    assert "| shallow |" in text and "| isomap |" in text and "## Wall time" in text
    assert (root / "board/leaderboard.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_same_bench_command_resumes_and_records_its_session(tiny_bench):
    root, args = tiny_bench
    again = run_cmd(*args, "--workers", 1, timeout=600)
    assert again.returncode == 0, again.stderr
    record = json.loads((root / "out/tiny-v1/shallow/grid/bench.json").read_text())
    assert len(record["sessions"]) == 2 and all(s["wall_s"] is not None for s in record["sessions"])


def test_the_leaderboard_refuses_what_would_not_compare(tiny_bench, tmp_path):
    root, _ = tiny_bench
    copy = tmp_path / "copy"
    shutil.copytree(root / "out", copy)
    again = run_cmd("smtrain", "leaderboard", root / "out", copy, "--out", tmp_path / "b")
    assert again.returncode != 0 and "not pooled" in again.stderr and len(again.stderr.splitlines()) == 1
    edited = copy / "tiny-v1/shallow/grid/bench.json"
    record = json.loads(edited.read_text())
    record["task"]["steps"] = 30
    edited.write_text(json.dumps(record))
    bad = run_cmd("smtrain", "leaderboard", copy, "--out", tmp_path / "b")
    assert bad.returncode != 0 and "another protocol" in bad.stderr and "(steps differ)" in bad.stderr
    record["task"]["steps"] = 60  # back to the suite's: a session that never ended shows as "≥"
    record["sessions"].append(record["sessions"][0] | {"wall_s": None, "outcome": None})
    edited.write_text(json.dumps(record))
    interrupted = run_cmd("smtrain", "leaderboard", copy, "--out", tmp_path / "b")
    assert interrupted.returncode == 0, interrupted.stderr
    assert "| shallow | ≥ " in (tmp_path / "b/leaderboard.md").read_text()
    (copy / "tiny-v1/shallow/grid/scores.json").unlink()
    partial = run_cmd("smtrain", "leaderboard", copy, "--out", tmp_path / "b")
    assert partial.returncode == 0 and "is left out" in partial.stderr
    cells = json.loads((tmp_path / "b/leaderboard.json").read_text())["cells"]
    assert {c["entry"] for c in cells} == {"isomap"}


def test_a_result_made_on_other_terms_is_refused_before_anything_runs(tiny_bench, tmp_path):
    root, args = tiny_bench
    copy = tmp_path / "out"
    shutil.copytree(root / "out", copy)
    edited = copy / "tiny-v1/isomap/grid/bench.json"  # the second entry: refused before the first resumes
    record = json.loads(edited.read_text())
    record["entry"]["params"] = {"neighbours": 5}
    edited.write_text(json.dumps(record))
    before = {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()}
    for extra in ([], ["--dry-run"]):
        again = run_cmd(*args[:-1], copy, *extra, "--workers", 1, timeout=600)
        assert again.returncode != 0 and len(again.stderr.strip().splitlines()) == 1, again.stderr
        assert "tiny-v1/isomap/grid holds a result of another entry (isomap (neighbours=5)" in again.stderr
        assert {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()} == before
    edited.write_text("{not json")
    corrupt = run_cmd(*args[:-1], copy, "--workers", 1, timeout=600)
    assert corrupt.returncode != 0 and "bench.json is not readable JSON" in corrupt.stderr


def test_a_bench_of_one_task_runs_only_it(tiny_bench, tmp_path):
    root, _ = tiny_bench
    args = ["smtrain", "bench", "tiny@2", "isomap", "--task", "grid6", "--lake", root / "lake", "--out", tmp_path]
    done = run_cmd(*args, "--workers", 1, timeout=600)
    assert done.returncode == 0, done.stderr
    assert [p.name for p in (tmp_path / "tiny-v2/isomap").iterdir()] == ["grid6"]
    wrong = run_cmd(*args[:-4], "--task", "nope", "--out", tmp_path)
    assert wrong.returncode != 0 and "suite tiny-v2 has no task 'nope'" in wrong.stderr


def test_a_walk_task_trains_and_scores_on_walks_and_its_result_verifies(tmp_path):
    """tiny@3's grid-walk: the bench generates the task's walks (the -walk datasets, as smgen would),
    a learned entry trains on them (its runs record the exploration as a term), isomap embeds them,
    and both results verify on the leaderboard, which checks the walk datasets' ids and hashes."""
    lake, out = tmp_path / "lake", tmp_path / "out"
    args = ["smtrain", "bench", "tiny@3", "sensorimotor", "isomap", "--task", "grid-walk", "--lake", lake]
    done = run_cmd(*args, "--out", out, "--workers", 2, timeout=600)
    assert done.returncode == 0, done.stderr
    made = sorted(p.parent.name for p in lake.glob("*/manifest.json"))
    assert made == [f"grid-seed{w}-{m}-walk" for w in (0, 1) for m in ("MM", "MME")]
    result = out / "tiny-v3/sensorimotor/grid-walk"
    walk = {"kind": "walk", "length": 50, "step": 1.0}
    assert json.loads((result / "bench.json").read_text())["task"]["exploration"] == walk
    configs = [json.loads(p.read_text()) for p in result.rglob("config.json")]
    assert len(configs) == 4 and all(c["exploration"] == walk for c in configs)
    # a network's h is float32 and stored so (half the bytes); isomap's needs float64
    for entry, dtype in (("sensorimotor", np.float32), ("isomap", np.float64)):
        stored = sorted((out / f"tiny-v3/{entry}/grid-walk/evidence").glob("*.npy"))
        assert stored and all(np.load(p).dtype == dtype for p in stored), entry
    board = run_cmd("smtrain", "leaderboard", out, "--out", tmp_path / "board")
    assert board.returncode == 0, board.stderr
    assert len(json.loads((tmp_path / "board/leaderboard.json").read_text())["results"]) == 2


def test_a_bench_dry_run_budgets_every_entry_on_every_task_and_writes_nothing(tiny_bench, tmp_path):
    _, args = tiny_bench
    fresh = run_cmd("smtrain", "bench", "tiny@2", "shallow", "isomap", "--dry-run", "--lake", tmp_path / "lake",
                    "--out", tmp_path / "out", "--workers", 1, timeout=600)  # fmt: skip
    assert fresh.returncode == 0, fresh.stderr
    lines = [line for line in fresh.stdout.splitlines() if not line.startswith("note: the cores are busy")]  # load
    assert [line.split(":")[0] for line in lines if not line.startswith(" ")][:-2] == [
        line for task in ("grid", "grid6")
        for line in (f"tiny-v2 task {task}", *(f"tiny-v2 {entry} on {task}" for entry in ("shallow", "isomap")))
    ]  # fmt: skip
    assert "tiny-v2 task grid6: datasets of grid6: 1, 0 in " in fresh.stdout, fresh.stdout
    assert "  runs: 4 new, 0 to resume, 0 finished" in lines and "  runs: 1 new, 0 to resume, 0 finished" in lines
    assert lines[-2].startswith("bench: about ") and lines[-1] == "dry run: nothing was written"
    assert list(tmp_path.iterdir()) == []
    done = run_cmd(*args, "--dry-run", "--workers", 1, timeout=600)  # the tiny bench ran: nothing left to train
    assert done.returncode == 0 and "  runs: 0 new, 0 to resume, 4 finished" in done.stdout, done.stderr


def test_a_bench_of_an_unknown_entry_writes_nothing(tmp_path):
    done = run_cmd("smtrain", "bench", "tiny", "nonesuch", "--lake", tmp_path / "lake", "--out", tmp_path / "out")
    assert done.returncode != 0 and "unknown model 'nonesuch'" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()
    assert not (tmp_path / "lake").exists()


def test_the_leaderboard_reads_results_on_object_storage(tiny_bench, tmp_path):
    """The files per task that a result is (bench.json, scores.json, evidence/), published to a bucket (a moto server on
    127.0.0.1): the leaderboard read from s3:// is the one read from the folder."""
    from .servers import moto_s3, s3fs_for

    root, _ = tiny_bench
    with moto_s3(tmp_path / "moto.log") as env:
        fs = s3fs_for(env)
        for path in (root / "out").rglob("*"):
            if path.name in ("bench.json", "scores.json") or path.parent.name == "evidence":
                fs.pipe_file(f"lake/results/{path.relative_to(root / 'out').as_posix()}", path.read_bytes())
        remote = run_cmd("smtrain", "leaderboard", "s3://lake/results", "--out", tmp_path / "remote", env=env)
        assert remote.returncode == 0, remote.stderr
    here = run_cmd("smtrain", "leaderboard", root / "out", "--out", tmp_path / "local")
    assert here.returncode == 0, here.stderr
    local = json.loads((tmp_path / "local/leaderboard.json").read_text())["cells"]
    assert json.loads((tmp_path / "remote/leaderboard.json").read_text())["cells"] == local


def test_an_entrys_parameters_reach_its_study_and_name_its_folder():
    import tomllib

    from smspace.bench.cli import parse_entry
    from smspace.bench.run import task_request

    entry = parse_entry("contrastive:temperature=0.2,embedding=16")
    assert entry.params == {"embedding": 16, "temperature": 0.2}
    assert entry.folder == "contrastive,embedding=16,temperature=0.2"
    request = task_request(get_suite("tiny@1").tasks[0], entry)
    assert request.study.train["model_params"] == entry.params
    study = tomllib.loads(request.source.decode())  # what is recorded beside the runs
    assert study["train"]["model"] == "contrastive" and study["train"]["model_params"] == entry.params
    assert study["train"]["steps"] == 60 and study["study"]["worlds"] == 2
    for bad in ("contrastive:temperature", "contrastive:=1"):
        with pytest.raises(SmspaceError, match="NAME:key=value"):
            parse_entry(bad)
    with pytest.raises(SmspaceError, match="learns nothing"):
        parse_entry("isomap:k=3")
    with pytest.raises(SmspaceError, match="unknown parameter 'note'"):
        parse_entry("contrastive:note=a/b")


def test_the_dimension_is_of_h_over_positions_not_of_its_clusters():
    """Five motor states per grid position: an h that is a noisy affine image of p has clusters of
    five, which local PCA alone reads as 1.6 dimensions; over the positions it is the plane's 2."""
    from smspace.metrics.dimension import local_pca_dimension
    from smspace.metrics.scores import SCORES, mean_per_position

    _, p = Dataset.open(SAMPLES / "grid-seed0-MM").regular_sampling()
    rng = np.random.default_rng(0)
    h = np.c_[p, np.zeros(len(p))] @ rng.normal(size=(3, 3)) + 0.01 * rng.normal(size=(len(p), 3))
    assert len(mean_per_position(h, p)) == len(np.unique(p, axis=0)) == 25
    assert local_pca_dimension(h) < 1.8 and SCORES["local_dim"].compute(h, p, 0) == 2.0


@pytest.mark.parametrize("model", ["motor-autoencoder", "beta-vae", "latent-forward"])
def test_a_baseline_with_its_own_objective_trains_on_two_ranks(tmp_path, model):
    """DDP averages gradients only through the module it wraps: the objective goes through it
    (train/model.py, Method), or rank 1's weights would drift from rank 0's, which every
    evaluation compares (a mismatch stops the run). The β-VAE's noise differs by rank (each its
    own rows) and the latent forward model's EMA target follows identical weights on each rank."""
    out = tmp_path / "run"
    args = ["smtrain", "fit", SAMPLES / "grid-seed0-MME", "--model", model, "--nproc", 2]
    done = run_cmd(*args, "--steps", 60, "--eval-every", 30, "--out", out, timeout=300)
    assert done.returncode == 0, done.stderr
    run = RunDir.open(out)
    rows = run.view.metrics()
    assert run.view.status().state == "finished" and run.view.config.world_size == 2
    assert rows[-1]["train_loss"] < rows[1]["train_loss"], rows


def test_the_leaderboards_columns_follow_the_suites_order_of_tasks():
    from smspace.bench.leaderboard import columns

    cell = {"suite": "spatial", "version": 2}
    given = [("floor24", "MM"), ("grid", "MME"), ("arm", "MEM"), ("grid", "MEM"), ("floor2", "MME"), ("grid6", "MM")]
    table = [cell | {"task": task, "mode": mode} for task, mode in given]
    expected = [("grid", "MEM"), ("grid", "MME"), ("grid6", "MM"), ("arm", "MEM"), ("floor2", "MME"), ("floor24", "MM")]
    assert columns(table) == expected


def test_a_models_noise_is_the_runs_own_and_repeats_from_its_seed():
    """The engine's noise (train/engine.py, step_noise) depends on the run's seed, rank and step
    alone: a run alone and stacked, and a resumed run, draw the same; two steps, two ranks or two
    seeds draw different numbers."""
    from smspace.train.engine import step_noise

    cpu = torch.device("cpu")
    both = step_noise([3, 4], 7, 0, 5, 6, cpu)
    assert both.shape == (2, 5, 6) and torch.equal(both[0], step_noise([3], 7, 0, 5, 6, cpu)[0])
    others = [step_noise([3], 8, 0, 5, 6, cpu), step_noise([3], 7, 1, 5, 6, cpu), both[1:]]
    assert all(not torch.allclose(both[:1], o) for o in others)
    assert abs(float(step_noise([0], 1, 0, 4000, 8, cpu).std()) - 1) < 0.05


@pytest.mark.parametrize("model", ["beta-vae", "latent-forward"])
def test_a_resumed_vae_or_ema_run_ends_bit_identical_to_one_never_stopped(tmp_path, model):
    """Noise by (seed, rank, step) and an EMA target held in the checkpoint's buffers: stopping at
    step 20 and resuming changes no byte of the weights at step 40."""
    straight = RunDir.create(tmp_path / "straight", config(model), False)
    fit(config(model), straight)
    stopped = RunDir.create(tmp_path / "stopped", config(model), False)
    with pytest.raises(KeyboardInterrupt):
        fit(config(model), stopped, sinks=[StopAt(20)])
    assert RunDir.open(stopped.view.local_path).view.checkpoint_step() == 20
    fit(config(model), RunDir.open(stopped.view.local_path), resume=True)
    a, b = weights(straight), weights(RunDir.open(stopped.view.local_path))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_the_latent_forward_models_target_follows_its_encoder_as_an_average(tmp_path):
    """The target is not trained by the optimiser but moved after each step: after 40 steps it has
    left its initial weights and lies between them and the online encoder's."""
    cfg = config("latent-forward")
    run = RunDir.create(tmp_path / "run", cfg, False)
    fit(cfg, run)
    manifest = Dataset.open(cfg.dataset).manifest
    shape = manifest.n_motor, math.prod(manifest.sensor_shape)
    initial = build(run.view.config, *shape, torch.device("cpu"))[0].state_dict()
    trained = weights(run)
    start, target, online = initial["target.w0"], trained["target.w0"], trained["sensation.0.weight"]
    assert torch.equal(start, initial["sensation.0.weight"])  # the target starts as a copy
    assert 0 < float((target - start).norm()) < float((online - start).norm())
