"""No write of smspace follows a symbolic link out of the tree it was given: a `.lock` made a link
was followed and its target truncated, with a pid written into it (issue: faults on the study,
plugin and storage surfaces, 1)."""

from __future__ import annotations

import shutil

from .conftest import SAMPLES, failed_in_one_line, run_cmd, short_fit

one_error = failed_in_one_line


def fit(out):
    return short_fit("grid-seed0-MM", SAMPLES, out)


def test_a_lock_that_is_a_link_is_refused_and_its_target_untouched(tmp_path):
    run, victim = tmp_path / "run", tmp_path / "victim.txt"
    assert fit(run).returncode == 0
    victim.write_text("precious")
    (run / ".lock").unlink()
    (run / ".lock").symlink_to(victim)
    line = one_error(run_cmd("smtrain", "fit", "--resume", run, "--steps", 60))
    assert ".lock: it is a symbolic link" in line, line
    assert victim.read_text() == "precious"


def test_the_lake_lock_of_a_dataset_is_never_followed(tmp_path):
    lake, victim = tmp_path / "lake", tmp_path / "victim.txt"
    victim.write_text("precious")
    (lake / ".locks").mkdir(parents=True)
    (lake / ".locks" / "grid-seed0-MM.lock").symlink_to(victim)
    result = run_cmd("smgen", "generate", "--setup", "grid", "--mode", "MM", "--transitions", 3000, "--lake", lake)
    assert "it is a symbolic link" in one_error(result)
    assert victim.read_text() == "precious"


def test_a_run_s_sub_folder_that_is_a_link_is_never_written_through(tmp_path):
    run, elsewhere = tmp_path / "run", tmp_path / "elsewhere"
    assert fit(run).returncode == 0
    elsewhere.mkdir()
    shutil.rmtree(run / "tensorboard")
    (run / "tensorboard").symlink_to(elsewhere)
    line = one_error(run_cmd("smtrain", "fit", "--resume", run, "--steps", 60))
    assert "tensorboard is a symbolic link; smspace writes only inside the folders it made" in line, line
    assert not any(elsewhere.iterdir())


def test_a_study_s_run_folder_that_is_a_link_is_never_written_through(tmp_path):
    lake, out, elsewhere = tmp_path / "lake", tmp_path / "runs", tmp_path / "elsewhere"
    args = ["sweep", "--setup", "grid", "--modes", "MM", "--worlds", 1, "--transitions", 3000, "--steps", 40,
            "--eval-every", 20, "--lake", lake, "--out", out, "--workers", 1]  # fmt: skip
    assert run_cmd("smtrain", *args).returncode == 0
    (run,) = [p for p in out.iterdir() if p.is_dir()]
    shutil.move(run, elsewhere)
    run.symlink_to(elsewhere)
    before = sorted(p.name for p in elsewhere.rglob("*"))
    line = one_error(run_cmd("smtrain", *args[:-2], "--steps", 60, "--workers", 1))
    assert "is a symbolic link" in line, line
    assert sorted(p.name for p in elsewhere.rglob("*")) == before
