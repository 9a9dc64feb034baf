"""A researcher's own grid study (a setup x model x N_h grid with the plugin demo's setup and
network): its report compares the combinations, renders in a CommonMark viewer, and leaves out a
run that never evaluated instead of failing."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from smspace.train.run_dir import RunDir, RunView

from .conftest import run_cmd

GRID_STUDY = """
[study]
modes = ["MM", "MME"]
worlds = 2
seed = 3
transitions = 3000

[train]
steps = 60
eval_every = 30
batch_size = 50

[grid]
setup = ["grid", "line"]
model = ["sensorimotor", "shallow"]
n_h = [2, 3]

[run]
workers = 2
"""


@pytest.fixture(scope="module")
def grid_study(tmp_path_factory) -> Path:
    """The study folder of a 2 x 2 x 2 grid, trained once for this module."""
    from smspace.datagen.setups import setup_names

    if "line" not in setup_names():
        pytest.fail("examples/plugin-demo is not installed: run `bash scripts/setup.sh`")
    root = tmp_path_factory.mktemp("grid-study")
    (root / "grid.toml").write_text(GRID_STUDY)
    done = run_cmd("smtrain", "sweep", root / "grid.toml", "--lake", root / "lake", "--out", root / "out", timeout=900)
    assert done.returncode == 0, done.stderr
    return root / "out"


def report(*args) -> tuple[Path, str]:
    out = Path(args[-1])
    done = run_cmd("smtrain", "report", *args[:-1], "--out", out, timeout=600)
    assert done.returncode == 0, done.stderr
    return out, done.stderr


def rendered_images(page: Path) -> list[str]:
    """The image sources a CommonMark renderer finds in report.md."""
    from markdown_it import MarkdownIt

    sources = []
    for token in MarkdownIt("commonmark").parse(page.read_text()):
        for child in token.children or []:
            if child.type == "image":
                sources.append(child.attrs["src"])
    return sources


def test_the_report_of_a_grid_compares_its_combinations(grid_study, tmp_path):
    out, _ = report(grid_study, tmp_path / "report")
    with open(out / "final.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 8 * 2  # eight combinations, two modes each
    assert {(r["setup"], r["model"], r["n_h"]) for r in rows} == {
        (s, m, n) for s in ("grid", "line") for m in ("sensorimotor", "shallow") for n in ("2", "3")
    }
    with open(out / "runs.csv") as fh:
        runs = list(csv.DictReader(fh))
    assert len(runs) == 8 * 2 * 2 and "model" in runs[0]
    assert all(Path(r["path"], "config.json").exists() for r in runs)
    assert len({r["path"] for r in runs}) == len(runs)  # run names repeat across combinations, paths do not
    from smspace.metrics.scores import scores_of
    from smspace.train.run_dir import RunView

    for r in runs[:: len(runs) // 4]:  # the bench's scores, measured on the h the last evaluation saved
        run = RunView.open(r["path"])
        measured = scores_of(*run.embeddings(int(r["step"])), run.config.seed)
        assert float(r["probe_r2"]) == measured["probe_r2"] and float(r["local_dim"]) == measured["local_dim"], r
        assert float(r["d_metric"]) == run.metrics()[-1]["d_metric"]  # the recorded metrics as recorded
    assert "local-PCA dimension of h" in (out / "final.md").read_text().splitlines()[0]
    for variable in ("setup", "model", "n_h"):
        assert (out / f"compare_{variable}.png").stat().st_size > 10_000, variable
    images = rendered_images(out / "report.md")
    assert images == [line.split("](")[1].rstrip(")") for line in (out / "report.md").read_text().splitlines()
                      if line.startswith("![")]  # fmt: skip
    assert len(images) >= 3 + 8 * 3 and all((out / src).is_file() for src in images)
    assert all(src == src.strip() and not set(src) & set(" {}'\"<>()") for src in images)


def test_a_report_into_its_own_folder_again_leaves_no_stale_figure(grid_study, tmp_path):
    out, _ = report(grid_study, tmp_path / "report")
    mine = out / "notes.txt"
    mine.write_text("the researcher's own file")
    one = next(p for p in sorted(grid_study.iterdir()) if p.is_dir() and "model=shallow" in p.name)
    report(one, out)
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == ["curves.png", "projection_MM.png", "projection_MME.png"], pngs
    assert mine.read_text() == "the researcher's own file"
    assert all((out / src).is_file() for src in rendered_images(out / "report.md"))


def test_a_run_that_never_evaluated_is_left_out_and_named(grid_study, tmp_path):
    study = tmp_path / "study"
    combination = next(p for p in sorted(grid_study.iterdir()) if p.is_dir())
    run = next(p for p in sorted(combination.iterdir()) if (p / "config.json").exists())
    (study / combination.name).mkdir(parents=True)
    broken = RunDir.create(study / combination.name / "failed-run", RunView.open(run).config, False)
    broken.set_status("failed", 0, "the plugin raised at step 0")
    for other in sorted(combination.iterdir()):
        if (other / "config.json").exists() and other != run:
            (study / combination.name / other.name).symlink_to(other, target_is_directory=True)
    out, said = report(study, tmp_path / "report")
    assert "left out" in said and "failed-run" in said and "the plugin raised at step 0" in said
    assert "failed-run" in (out / "report.md").read_text()
    with open(out / "runs.csv") as fh:
        assert len(list(csv.DictReader(fh))) == 3  # the other runs of the combination, reported


def test_titles_name_the_network_and_its_precision(grid_study):
    from smspace.train.report import by_study, expand_runs, load_runs

    studies = by_study(load_runs(expand_runs([grid_study])))
    labels = {st.label for st in studies}
    assert {label.rsplit("; ", 1)[1] for label in labels} == {"shallow, fp32", "sensorimotor, fp32"}
    config = json.loads(next(grid_study.glob("*/*/config.json")).read_text())
    assert config["precision"] == "fp32"


def test_ls_lists_into_study_and_grid_folders_with_the_network(grid_study):
    listed = run_cmd("smtrain", "ls", "--runs", grid_study, "--json")
    assert listed.returncode == 0, listed.stderr
    rows = [json.loads(line) for line in listed.stdout.splitlines()]
    assert len(rows) == 8 * 2 * 2 and {r["state"] for r in rows} == {"finished"}
    assert len({r["study"] for r in rows}) == 8 and all(r["name"].startswith(r["study"] + "/") for r in rows)
    assert {r["model"] for r in rows} == {"sensorimotor", "shallow"} and {r["precision"] for r in rows} == {"fp32"}
    above = run_cmd("smtrain", "ls", "--runs", grid_study.parent)  # the folder holding the study
    lines = above.stdout.splitlines()
    assert above.returncode == 0 and len(lines) == 1 + 8 * 2 * 2, above.stdout
    assert lines[1].startswith(f"{grid_study.name}/setup=grid,model=sensorimotor,n_h=2/grid-seed3-MM-nh2-seed3")
    assert "shallow fp32" in above.stdout
    info = run_cmd("smtrain", "info", rows[-1]["run"])
    assert "model: shallow" in info.stdout and "precision: fp32" in info.stdout, info.stdout


def hparams_view(root: Path) -> dict[str, tuple[dict, dict]]:
    """What TensorBoard's HParams tab shows for `--logdir root`: {run: (hparams, last metrics)},
    through the plugin's own backend."""
    from tensorboard import context
    from tensorboard.backend.event_processing import data_provider, plugin_event_multiplexer
    from tensorboard.plugins import base_plugin
    from tensorboard.plugins.hparams import api_pb2, backend_context, list_session_groups

    mux = plugin_event_multiplexer.EventMultiplexer()
    mux.AddRunsFromDirectory(str(root))
    mux.Reload()
    provider = data_provider.MultiplexerDataProvider(mux, str(root))
    backend = backend_context.Context(base_plugin.TBContext(data_provider=provider, logdir=str(root)))
    request = api_pb2.ListSessionGroupsRequest(start_index=0, slice_size=1000, allowed_statuses=range(5))
    groups = list_session_groups.Handler(context.RequestContext(), backend, "", request).run().session_groups
    return {
        g.name: (
            {k: getattr(v, v.WhichOneof("kind")) for k, v in g.hparams.items()},
            {m.name.tag: (m.training_step, m.value) for m in g.metric_values},
        )
        for g in groups
    }


def test_tensorboard_compares_the_grid_in_its_hparams_tab_one_stream_per_run(grid_study):
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

    view = hparams_view(grid_study)
    runs = sorted(p.parent for p in grid_study.glob("*/*/config.json"))
    assert sorted(view) == sorted(str(r.relative_to(grid_study)) for r in runs)  # named after the run folder
    for run in runs:
        hparams, metrics = view[str(run.relative_to(grid_study))]
        config = json.loads((run / "config.json").read_text())
        assert hparams["setup"] == config["setup"] and hparams["model"] == config["model"]
        assert hparams["n_h"] == config["n_h"] and hparams["precision"] == config["precision"]
        assert json.loads(hparams["model_params"]) == config["model_params"]
        last = RunView.open(run).metrics()[-1]
        assert metrics["space/D_metric"] == (last["step"], pytest.approx(last["d_metric"], rel=1e-6))
        (stream,) = run.glob("*tfevents*")  # one stream, read in order
        steps = [e.step for e in EventFileLoader(str(stream)).Load() if e.HasField("summary")]
        assert steps == sorted(steps) and steps[-1] == last["step"]
    assert {h["model"] for h, _ in view.values()} == {"sensorimotor", "shallow"}


def test_overrides_on_the_command_line_apply_on_top_of_the_file_and_are_recorded(tmp_path):
    from smspace.common.errors import SmspaceError
    from smspace.study.file import load_study

    path = tmp_path / "s.toml"
    path.write_text(GRID_STUDY)
    study = load_study(path, ["train.steps=2000", "grid.n_h=[3,5]", "train.model=shallow", "study.worlds=3"])
    assert study.train["steps"] == 2000 and study.grid["n_h"] == [3, 5] and study.worlds == 3
    assert "model" not in study.grid and study.train["model"] == "shallow"  # moved out of [grid]
    assert {c["n_h"] for c in study.combinations()} == {3, 5} and len(study.combinations()) == 4
    for bad, named in (("steps=5", "expected section.key=value"), ("train.steps=0", "train.steps"),
                       ("grid.n_h=3", "grid.n_h"), ("trian.steps=5", "expected section.key=value")):  # fmt: skip
        with pytest.raises(SmspaceError, match=named):
            load_study(path, [bad])
    lake, out = tmp_path / "lake", tmp_path / "out"
    given = ['grid.setup=["grid"]', 'grid.model=["sensorimotor"]', "grid.n_h=[3]", "study.worlds=1",
             'study.modes=["MM"]', "train.steps=30"]  # fmt: skip
    done = run_cmd("smtrain", "sweep", path, *given, "--lake", lake, "--out", out)
    assert done.returncode == 0, done.stderr
    (where, final), *_ = [line.split("\t") for line in done.stdout.splitlines()]  # as a lone fit ends
    assert Path(where).name == "grid-seed3-MM-nh3-seed3" and json.loads(final)["step"] == 30
    assert json.loads(final)["state"] == "finished" and json.loads(final)["d_topo"] > 0
    recorded = json.loads((out / "study-file.json").read_text())
    assert recorded["overrides"][-1] == "train.steps=30" and recorded["train"]["steps"] == 30
    (combination,) = recorded["combinations"]  # as it trains: its setup, every flag with its default
    assert combination["setup"] == "grid" and combination["folder"] == "setup=grid,model=sensorimotor,n_h=3"
    assert combination["train"]["lr_start"] == 0.001 and combination["train"]["encoder_layers"] == [150, 100, 50]
    assert [p.name for p in out.iterdir() if p.is_dir()] == ["setup=grid,model=sensorimotor,n_h=3"]
    refused = run_cmd("smtrain", "sweep", "--setup", "grid", "train.steps=3", "--out", out)
    assert refused.returncode == 2 and "overrides apply to a study file" in refused.stderr


def test_pairs_take_values_together_and_a_combination_given_twice_is_one(tmp_path):
    from smspace.common.errors import SmspaceError
    from smspace.study.file import folder_name, load_study

    path = tmp_path / "s.toml"
    path.write_text(
        '[study]\nsetup = "grid"\n[grid]\nn_h = [2, 3]\n'
        '[pairs]\nmodel = ["sensorimotor", "shallow", "shallow"]\nmodel_params = [{}, {width = 48}, {width = 48}]\n'
    )
    names = [folder_name(c) for c in load_study(path).combinations()]
    assert names == [
        "n_h=2,model=sensorimotor,model_params=none", "n_h=2,model=shallow,model_params=width48",
        "n_h=3,model=sensorimotor,model_params=none", "n_h=3,model=shallow,model_params=width48",
    ]  # fmt: skip
    path.write_text('[study]\nsetup = "grid"\n[pairs]\nmodel = ["sensorimotor", "shallow"]\nn_h = [2]\n')
    with pytest.raises(SmspaceError, match=r"pairs: lists of different lengths \(model 2, n_h 1\)"):
        load_study(path)
    path.write_text('[study]\nsetup = "grid"\n[grid]\nn_h = [2]\n[pairs]\nn_h = [3]\n')
    with pytest.raises(SmspaceError, match=r"pairs\.n_h: is also set in"):
        load_study(path)


def test_a_combination_a_network_refuses_is_named_with_its_file_and_pairs_avoid_it(tmp_path):
    crossed = tmp_path / "crossed.toml"
    crossed.write_text(
        '[study]\nsetup = "grid"\nmodes = ["MM"]\n[grid]\nmodel = ["sensorimotor", "shallow"]\n'
        "model_params = [{width = 48}]\n"
    )
    refused = run_cmd("smtrain", "sweep", crossed, "--dry-run", "--lake", tmp_path / "lake", "--out", tmp_path / "o")
    assert refused.returncode == 2, refused.stderr
    assert f"{crossed}: [model=sensorimotor,model_params=width48] model 'sensorimotor'" in refused.stderr
    paired = tmp_path / "paired.toml"
    paired.write_text(
        '[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n[train]\nsteps = 100\n'
        '[pairs]\nmodel = ["sensorimotor", "shallow"]\nmodel_params = [{}, {width = 48}]\n'
    )
    dry = run_cmd("smtrain", "sweep", paired, "--dry-run", "--lake", tmp_path / "lake", "--out", tmp_path / "o")
    assert dry.returncode == 0, dry.stderr
    assert "2 combination(s)" in dry.stdout and "model=shallow,model_params=width48: 1 runs" in dry.stdout


def test_a_sweep_given_by_flags_has_a_dry_run_too(tmp_path):
    lake, out = tmp_path / "lake", tmp_path / "runs"
    flags = ["--setup", "grid", "--modes", "MM,MME", "--worlds", 2, "--transitions", 3000, "--steps", 200, "--nh", 4]
    dry = run_cmd("smtrain", "sweep", *flags, "--dry-run", "--lake", lake, "--out", out)
    assert dry.returncode == 0, dry.stderr
    assert "(the flags of smtrain sweep): setup grid, modes MM,MME, worlds 0..1" in dry.stdout
    assert "(no grid): 4 runs, 800 run-steps to train" in dry.stdout and "runs: 4 new, 0 to resume" in dry.stdout
    assert not lake.exists() and not out.exists()


def test_the_dry_run_measures_what_a_plugin_setup_stores_per_transition(grid_study, tmp_path):
    """The lake estimate used a fixed 16 bytes per transition for any plugin setup (625 KiB said,
    3.5 MB written); it is measured on the setup's own encoded transitions now."""
    import re

    (tmp_path / "grid.toml").write_text(GRID_STUDY)
    dry = run_cmd(
        "smtrain", "sweep", tmp_path / "grid.toml", "--dry-run", "--lake", tmp_path / "lake", "--out", tmp_path / "o"
    )
    assert dry.returncode == 0, dry.stderr
    for setup in ("grid", "line"):
        said = re.search(rf"datasets of {setup}: .* at ([0-9.e+]+) bytes each", dry.stdout)
        assert said, dry.stdout
        shards = [p for p in (grid_study.parent / "lake").glob(f"{setup}-seed*/shard-*.mcap")]
        written = sum(p.stat().st_size for p in shards) / (2 * 2 * 3000)  # two worlds, two modes
        assert 0.5 * written < float(said[1]) < 2 * written, (setup, said[1], written)
    assert "time: about" in dry.stdout and "starting)" in dry.stdout


def test_report_and_dry_run_from_python(grid_study, tmp_path):
    import smspace

    page = smspace.report([grid_study], tmp_path / "report")
    assert page.name == "report.md" and (tmp_path / "report" / "compare_model.png").exists()
    runs = [smspace.open_run(p.parent) for p in sorted(grid_study.glob("*model=shallow*/*/config.json"))][:2]
    assert smspace.report(runs, tmp_path / "two").exists()
    study = tmp_path / "s.toml"
    study.write_text(GRID_STUDY)
    lines = smspace.dry_run(study, tmp_path / "o", lake=tmp_path / "lake", overrides=["train.steps=30"])
    assert lines[-1] == "dry run: nothing was written" and "8 combination(s)" in lines[0]
    assert not (tmp_path / "o").exists()


TINY = """
[study]
setup = "grid"
modes = ["MM"]
worlds = 2
seed = 5
transitions = 1000
[train]
steps = 20
eval_every = 10
batch_size = 50
"""


def test_a_script_that_starts_workers_without_a_main_guard_is_refused_before_any_write(tmp_path):
    """The script of docs/API.md runs with workers=2; the same lines without the guard are refused
    in one line naming the script's line, and nothing is written (neither runs nor datasets)."""
    import re
    import sys

    from .conftest import ROOT

    script = re.search(r"```py\n(# study.py.*?)```", (ROOT / "docs" / "API.md").read_text(), flags=re.S)[1]
    (tmp_path / "tiny.toml").write_text(TINY)
    (tmp_path / "grid.toml").write_text(GRID_STUDY)
    unguarded = script.replace('if __name__ == "__main__":', "if True:").replace("tiny.toml", "grid.toml")
    (tmp_path / "study.py").write_text(unguarded)
    refused = run_cmd(sys.executable, "study.py", cwd=tmp_path, timeout=300)
    assert refused.returncode == 1
    last = refused.stderr.strip().splitlines()[-1]
    assert last.endswith("study.py:5: smspace.run_study(workers=2) starts worker processes, which import this "
                         'script again and would run it again; put the call under `if __name__ == "__main__":` '
                         '(docs/API.md, "Scripts that start workers")'), last  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.toml", "study.py", "tiny.toml"]
    (tmp_path / "study.py").write_text(script)
    done = run_cmd(sys.executable, "study.py", cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "2"


def test_errors_raised_to_python_name_the_python_argument(grid_study, tmp_path):
    import smspace

    run = next(grid_study.glob("*/*/config.json")).parent
    with pytest.raises(smspace.SmspaceError) as refused:
        smspace.fit(RunView.open(run).config.dataset, out=run, steps=20)
    assert "call smspace.resume(run) to continue it or overwrite=True" in str(refused.value), refused.value
    assert "--" not in str(refused.value)
    with pytest.raises(smspace.SmspaceError, match=r"^n_h must be an integer in 1\.\.65536, got 0$"):
        smspace.fit(RunView.open(run).config.dataset, out=tmp_path / "r", n_h=0)
    changed = tmp_path / "grid.toml"
    changed.write_text(GRID_STUDY.replace("steps = 60", "steps = 60\nbatch_size = 40").replace("batch_size = 50\n", ""))
    with pytest.raises(smspace.SmspaceError) as other_terms:
        smspace.run_study(changed, out=grid_study, lake=grid_study.parent / "lake", workers=1)
    assert "overwrite=True" in str(other_terms.value) and "--" not in str(other_terms.value), other_terms.value
