"""What a careless operator types is refused in one line before anything is written (issue: faults
on the study, plugin and storage surfaces)."""

from __future__ import annotations

from functools import partial

import pytest

from .conftest import SAMPLES, failed_in_one_line, run_cmd

one_error = partial(failed_in_one_line, code=2, alone=True)


@pytest.mark.parametrize("name", ["../../escaped", "a/b", "/abs", ".hidden", "x" * 101])
def test_a_study_name_is_a_folder_name_not_a_path(tmp_path, name):
    """`name = "../../escaped"` without --out wrote the study outside the working folder, rc 0."""
    work = tmp_path / "work" / "deep"
    work.mkdir(parents=True)
    study = work / "study.toml"
    study.write_text(f'[study]\nname = "{name}"\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n'
                     '[train]\nsteps = 20\neval_every = 10\n')  # fmt: skip
    line = one_error(run_cmd("smtrain", "sweep", study, "--lake", tmp_path / "lake", cwd=work))
    assert "study.name" in line and "plain folder name" in line, line
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["deep", "study.toml", "work"]


def test_a_model_parameter_given_twice_is_refused(tmp_path):
    """`--model-params '{"width": 64, "width": 65}'` was taken, the last value winning."""
    out = tmp_path / "run"
    result = run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out,
                     "--model-params", '{"width": 64, "width": 65}')  # fmt: skip
    assert "'width' given twice" in one_error(result) and not out.exists()


@pytest.mark.parametrize(
    "train, needle",
    [
        ('device = "cuda"', "--device cuda: no CUDA GPU is usable here"),
        ("encoder_layers = [65536, 65536]", "GiB of memory"),
    ],
)
def test_a_study_this_machine_cannot_run_is_refused_before_anything_is_written(tmp_path, train, needle):
    """Refused only after datasets, study-file.*, study.json or run configs were written; the
    corrected file was then refused because of those leftovers."""
    import torch

    if "cuda" in train and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    study = tmp_path / "study.toml"
    study.write_text(f'[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n[train]\nsteps = 20\n{train}\n')
    lake, out = tmp_path / "lake", tmp_path / "runs"
    for dry in ([], ["--dry-run"]):
        line = one_error(run_cmd("smtrain", "sweep", study, "--lake", lake, "--out", out, *dry))
        assert needle in line, line
        assert not lake.exists() and not out.exists()


@pytest.mark.parametrize(
    "text, needle",
    [
        ("[grid]\nn_h = {a}\nlr_start = {b}\n", "combinations; at most 1000"),
        ("[run]\nworkers = 1000000\n", "run.workers"),
        ("[study]\nseed = 9223372036854775807\nworlds = 2\n", "passes the largest world seed"),
        ("[study]\ntransitions = 2199023255553\n", "study.transitions"),
    ],
)
def test_unbounded_studies_are_refused_at_once(tmp_path, text, needle):
    """A grid of 1000 x 1000 values took 8.7 s to parse and its dry run did not end; a million
    workers started a process per run; seed 2**63-1 with 2 worlds wrote a dataset that then read
    as corrupt."""
    text = text.format(a=list(range(1, 1001)), b=[i / 1e4 for i in range(1, 1001)])
    head = '[study]\nsetup = "grid"\nmodes = ["MM"]\n' if not text.startswith("[study]") else ""
    body = text.replace("[study]\n", '[study]\nsetup = "grid"\nmodes = ["MM"]\n') if not head else text
    study = tmp_path / "study.toml"
    study.write_text(head + body)
    line = one_error(run_cmd("smtrain", "sweep", study, "--lake", tmp_path / "lake", "--out", tmp_path / "o",
                             "--dry-run", timeout=60))  # fmt: skip
    assert needle in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.toml"]


def test_a_study_no_disk_here_can_hold_is_refused_not_budgeted(tmp_path):
    """The dry run budgeted impossible studies ("1.34e+08 TiB" of datasets, rc 0); generation
    would refuse them. Now the dry run and the run refuse them alike, before writing anything."""
    study = tmp_path / "study.toml"
    study.write_text('[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 1099511627776\n[train]\nsteps = 20\n')
    lake, out = tmp_path / "lake", tmp_path / "runs"
    for dry in (["--dry-run"], []):
        line = one_error(run_cmd("smtrain", "sweep", study, "--lake", lake, "--out", out, *dry, timeout=120))
        assert "of datasets; the disk of" in line or "this generation needs about" in line, line
        assert sorted(p.name for p in tmp_path.iterdir()) == ["study.toml"]


def test_a_run_stopped_before_its_first_checkpoint_is_told_what_works(tmp_path):
    """Killed before the first checkpoint (fit on S3, DDP), the launcher advised --resume, which
    said there was no checkpoint, and the original command said "already holds a run": only
    --overwrite worked. Every one of them now says so."""
    from smspace.train.run_dir import CHECKPOINT, METRICS, after_a_stop

    out = tmp_path / "run"
    command = ["smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--steps", 20, "--eval-every", 10, "--out", out]
    assert run_cmd(*command).returncode == 0
    (out / CHECKPOINT).unlink()  # what a kill before the first checkpoint leaves: the run's config
    (out / METRICS).unlink()
    assert "--overwrite" in after_a_stop(str(out), 2) and "--resume" not in after_a_stop(str(out), 2)
    again = one_error(run_cmd(*command))
    assert "stopped before its first checkpoint: pass --overwrite" in again, again
    resumed = one_error(run_cmd("smtrain", "fit", "--resume", out))
    assert "no checkpoint to resume from" in resumed and "--overwrite" in resumed, resumed
    assert run_cmd(*command, "--overwrite").returncode == 0
    assert "smtrain fit --resume" in after_a_stop(str(out)) and "step 20" in after_a_stop(str(out))


def test_a_study_of_another_name_does_not_take_over_a_study_s_folder(tmp_path):
    """A study of another name took over a study's folder with only a notice; the first study's
    re-run then said "no longer in the study:" followed by nothing."""
    body = '[study]\nname = "{name}"\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n'
    body += "[train]\nsteps = 20\neval_every = 10\n"
    lake, out = tmp_path / "lake", tmp_path / "runs"
    first, other = tmp_path / "a.toml", tmp_path / "b.toml"
    first.write_text(body.format(name="a"))
    other.write_text(body.format(name="b") + "[grid]\nn_h = [3]\n")
    assert run_cmd("smtrain", "sweep", first, "--lake", lake, "--out", out, "--workers", 1).returncode == 0
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    line = one_error(run_cmd("smtrain", "sweep", other, "--lake", lake, "--out", out, "--dry-run"))
    assert "holds the study 'a', not 'b'" in line, line
    line = one_error(run_cmd("smtrain", "sweep", other, "--lake", lake, "--out", out))
    assert "holds the study 'a', not 'b'" in line and sorted(p.relative_to(out) for p in out.rglob("*")) == before
    first.write_text(body.format(name="a") + "[grid]\nn_h = [3]\n")  # the same study, given a grid
    grown = run_cmd("smtrain", "sweep", first, "--lake", lake, "--out", out, "--workers", 1)
    assert grown.returncode == 0, grown.stderr
    assert "no longer in the study (their runs are kept, not trained): (the runs without a grid)" in grown.stderr


def test_a_study_file_read_from_a_pipe_is_recorded_as_given(tmp_path):
    """`smtrain sweep <(cat study.toml)` trained but recorded an empty study-file.toml (read twice)."""
    import subprocess

    from .conftest import BIN

    study = tmp_path / "study.toml"
    text = '[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n[train]\nsteps = 20\neval_every = 10\n'
    study.write_text(text)
    out = tmp_path / "runs"
    cmd = f"{BIN / 'smtrain'} sweep <(cat {study}) --lake {tmp_path / 'lake'} --out {out} --workers 1"
    done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (out / "study-file.toml").read_text() == text


def test_a_study_file_nested_thousands_deep_is_one_line(tmp_path):
    study = tmp_path / "deep.toml"
    study.write_text("[grid]\nn_h = " + "[" * 3000 + "]" * 3000 + "\n")
    line = one_error(run_cmd("smtrain", "sweep", study, "--dry-run", "--lake", tmp_path / "lake"))
    assert "nests its values too deeply" in line or "not valid TOML" in line, line


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """A finished one-run study, made once: the tampering tests copy it."""
    root = tmp_path_factory.mktemp("swept")
    study = root / "study.toml"
    study.write_text('[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n[train]\nsteps = 20\n'
                     'eval_every = 10\n[grid]\nn_h = [2, 3]\n')  # fmt: skip
    done = run_cmd("smtrain", "sweep", study, "--lake", root / "lake", "--out", root / "runs", "--workers", 1)
    assert done.returncode == 0, done.stderr
    return root


@pytest.mark.parametrize(
    "file, edit, needle",
    [
        ("study-file.json", lambda r: r | {"grid": {"n_h": 3}}, None),
        ("study-file.json", lambda r: r | {"grid": "x"}, None),
        ("study-file.json", lambda r: [r], "study-file.json is unreadable"),
        ("n_h=2/study.json", lambda r: r | {"ensembles": 5}, "study.json is unreadable"),
        ("n_h=2/study.json", lambda r: r | {"terms": r["terms"] | {"steps": "x"}}, "study.json is unreadable"),
        (
            "n_h=2/study.json",
            lambda r: r | {"terms": {k: v for k, v in r["terms"].items() if k != "steps"}},
            "study.json is unreadable",
        ),
        ("n_h=2/study.json", lambda r: r | {"ensembles": [r["ensembles"][0] * 2]}, "listed in two ensembles"),
    ],
)
def test_tampered_study_records_are_one_line(swept, tmp_path, file, edit, needle):
    import json
    import shutil

    root = tmp_path / "copy"
    shutil.copytree(swept, root)
    path = root / "runs" / file
    path.write_text(json.dumps(edit(json.loads(path.read_text()))))
    result = run_cmd("smtrain", "sweep", root / "study.toml", "--lake", swept / "lake", "--out", root / "runs",
                     "--workers", 1)  # fmt: skip
    assert "Traceback" not in result.stderr, result.stderr
    if needle is None:  # read as a changed study, said in one line, and run on
        assert result.returncode == 0 and "changed since it last ran" in result.stderr, result.stderr
    else:
        assert needle in one_error(result)


def test_a_tampered_status_is_listed_as_broken_not_a_traceback(swept, tmp_path):
    import json
    import shutil

    root = tmp_path / "copy"
    shutil.copytree(swept, root)
    (status,) = (root / "runs" / "n_h=2").glob("*/status.json")
    status.write_text(json.dumps(json.loads(status.read_text()) | {"step": "x"}))
    listed = run_cmd("smtrain", "ls", "--runs", status.parent.parent)
    assert listed.returncode == 0 and "Traceback" not in listed.stderr, listed.stderr
    assert "broken" in listed.stdout, listed.stdout


def test_smgen_ls_says_which_datasets_it_left_out(tmp_path):
    """A dataset with a corrupt manifest was left out of `smgen ls` with rc 0 and no note."""
    import shutil

    lake = tmp_path / "lake"
    shutil.copytree(SAMPLES, lake)
    (lake / "grid-seed0-MM" / "manifest.json").write_text("{not json")
    listed = run_cmd("smgen", "ls", "--lake", lake)
    assert listed.returncode == 0 and "grid-seed0-MME" in listed.stdout and "grid-seed0-MM " not in listed.stdout
    assert "1 dataset folder(s) left out, their manifest does not read: grid-seed0-MM" in listed.stderr, listed.stderr


def test_a_config_no_run_could_have_names_its_file(tmp_path):
    """A NaN lr_start in a run's config.json: "--lr-start must be a finite positive number" named no file."""
    import json

    run = tmp_path / "run"
    assert run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", run, "--steps", 20,
                   "--eval-every", 10).returncode == 0  # fmt: skip
    cfg = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps(cfg | {"lr_start": float("nan")}))
    line = one_error(run_cmd("smtrain", "fit", "--resume", run, "--steps", 40))
    assert f"{run}/config.json is not readable JSON (NaN is not a JSON number)" in line, line  # lake/records.py
    (run / "config.json").write_text(json.dumps(cfg | {"lr_start": -1.0}))
    line = one_error(run_cmd("smtrain", "fit", "--resume", run, "--steps", 40))
    assert f"{run}/config.json holds a config no run could have" in line, line


@pytest.mark.parametrize("value", ['"a\\u0000b"', '"' + "w" * 300 + '"'])
def test_a_grid_value_that_cannot_name_a_folder_is_one_line(tmp_path, value):
    """A NUL in a grid value, or a combination folder name over 255 bytes: tracebacks."""
    study = tmp_path / "study.toml"
    study.write_text('[study]\nsetup = "grid"\nmodes = ["MM"]\n[train]\nsteps = 20\nmodel = "sensorimotor"\n'
                     f'[grid]\nmodel_params = [{{tag = {value}}}]\n')  # fmt: skip
    line = one_error(run_cmd("smtrain", "sweep", study, "--lake", tmp_path / "lake", "--dry-run"))
    assert "cannot name a folder" in line, line


def test_a_metrics_file_missing_a_column_is_one_line(tmp_path):
    """A metrics file without d_topo: report died with a KeyError."""
    import pyarrow.parquet as pq

    run = tmp_path / "run"
    assert run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", run, "--steps", 20,
                   "--eval-every", 10).returncode == 0  # fmt: skip
    table = pq.read_table(run / "metrics.parquet")
    pq.write_table(table.drop_columns(["d_topo"]), run / "metrics.parquet")
    line = one_error(run_cmd("smtrain", "report", run, "--out", tmp_path / "report"))
    assert "metrics.parquet is unreadable (no column d_topo)" in line, line


def test_outputs_never_land_inside_their_inputs(tmp_path):
    """`sweep --out LAKE`, `--out LAKE/DATASET`, `fit --out` inside a dataset folder and `report
    --out RUN` were all accepted."""
    import shutil

    lake = tmp_path / "lake"
    shutil.copytree(SAMPLES, lake)
    before = sorted(str(p) for p in lake.rglob("*"))
    flags = ["--setup", "grid", "--modes", "MM", "--transitions", 3000, "--steps", 20, "--lake", lake]
    for out in (lake, lake / "grid-seed0-MM"):
        assert "runs and datasets live apart" in one_error(run_cmd("smtrain", "sweep", *flags, "--out", out))
    inside = lake / "grid-seed0-MM" / "run"
    line = one_error(run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", lake, "--out", inside, "--steps", 20))
    assert "lies inside the dataset it trains on" in line, line
    assert sorted(str(p) for p in lake.rglob("*")) == before
    run = tmp_path / "run"
    assert run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", lake, "--out", run, "--steps", 20,
                   "--eval-every", 10).returncode == 0  # fmt: skip
    line = one_error(run_cmd("smtrain", "report", run, "--out", run / "report"))
    assert "which it reports on" in line and not (run / "report").exists(), line


def _bounded_fields() -> list:
    from smspace.train.config import flag_fields

    return [f for f in flag_fields() if f.metadata["min"] is not None or f.metadata["max"] is not None]


@pytest.mark.parametrize("field", _bounded_fields(), ids=lambda f: f.name)
def test_a_bound_declared_once_holds_for_flags_study_files_and_the_api(tmp_path, field):
    """Training fields were validated three times (click types, the study-file reader, the config),
    and had drifted. Each bound is declared once, on the field (train/config.py), and refuses the
    same value on the command line, in a study file and from Python."""
    import smspace
    from smspace.study.file import NOT_TRAINABLE
    from smspace.train.config import flag_name

    low, high = field.metadata["min"], field.metadata["max"]
    value = high + 1 if high is not None else low - 1
    flag = flag_name(field)
    out = tmp_path / "run"
    line = one_error(run_cmd("smtrain", "fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, flag, value))
    assert flag in line and str(high if high is not None else low) in line, line
    study = tmp_path / "study.toml"
    study.write_text(f'[study]\nsetup = "grid"\nmodes = ["MM"]\ntransitions = 3000\n[train]\n{field.name} = {value}\n')
    line = one_error(run_cmd("smtrain", "sweep", study, "--dry-run", "--lake", tmp_path / "lake"))
    assert f"train.{field.name}" in line and (str(value) in line or field.name in NOT_TRAINABLE), line
    with pytest.raises(smspace.SmspaceError, match=f"^{field.name} must be an integer in"):  # its Python name
        smspace.fit("grid-seed0-MM", lake=SAMPLES, out=out, **{field.name: value})
    assert not out.exists() and not (tmp_path / "lake").exists()
