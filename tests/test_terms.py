"""The rules of train/terms.py: what a resume or an extended study may change, refused otherwise
in one line before anything is written."""

from __future__ import annotations

import json
from functools import partial

import pytest

from smspace.common.errors import SmspaceError
from smspace.train.run_dir import RunView

from .conftest import SAMPLES, failed_in_one_line, smtrain

error_line = partial(failed_in_one_line, prog="smtrain", code=2, alone=True)


def config_of(folder) -> dict:
    return json.loads((folder / "config.json").read_text())


def test_a_finished_run_is_never_shortened(tmp_path):
    out = tmp_path / "run"
    args = ["fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--eval-every", 20]
    assert smtrain(*args, "--steps", 60).exit_code == 0
    before = (out / "config.json").read_bytes(), (out / "checkpoint.pt").read_bytes()
    line = error_line(smtrain("fit", "--resume", out, "--steps", 40))
    assert "--steps 40 is fewer than the 60 steps" in line and "never shortened" in line
    assert ((out / "config.json").read_bytes(), (out / "checkpoint.pt").read_bytes()) == before
    assert RunView.open(out).status().state == "finished"


def test_an_unfinished_run_is_not_shortened_either(tmp_path):
    """A 600-step run stopped at step 40 and resumed with --steps 60 would end mid-decay."""
    out = tmp_path / "run"
    assert (
        smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 40, "--eval-every", 20).exit_code
        == 0
    )
    raw = config_of(out) | {"steps": 600, "lr_decay_steps": 480}  # as if it had been stopped at step 40 of 600
    (out / "config.json").write_text(json.dumps(raw))
    line = error_line(smtrain("fit", "--resume", out, "--steps", 60))
    assert "fewer than the 600 steps" in line and "over 480 steps" in line
    assert config_of(out)["steps"] == 600


def test_an_extension_keeps_the_schedule_says_so_and_is_recorded(tmp_path):
    out = tmp_path / "run"
    assert (
        smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 40, "--eval-every", 20).exit_code
        == 0
    )
    result = smtrain("fit", "--resume", out, "--steps", 80)
    assert result.exit_code == 0, result.stderr
    assert "extending" in result.stderr and "from 40 to 80 steps on its recorded schedule" in result.stderr
    assert "over 32 steps" in result.stderr  # 80 % of the 40 it was created with, not of 80
    cfg = config_of(out)
    assert cfg["steps"] == 80 and cfg["lr_decay_steps"] == 32
    assert cfg["extensions"] == [{"from_steps": 40, "to_steps": 80}]
    assert [r["step"] for r in RunView.open(out).metrics()] == [0, 20, 40, 60, 80]


def sweep(out, lake, *extra):
    return smtrain(
        "sweep", "--setup", "grid", "--modes", "MM", "--seed", 4, "--transitions", 2500, "--eval-every", 20,
        "--lake", lake, "--out", out, "--gen-workers", 1, "--workers", 1, *extra,
    )  # fmt: skip


def test_a_study_extended_with_more_worlds_keeps_one_schedule_for_all(tmp_path):
    """--worlds 2 --steps 40, then --worlds 3 --steps 60 into the same --out: before, worlds 4-5 kept
    a decay over 32 steps and world 6 got one over 48, and a report pooled them."""
    out, lake = tmp_path / "runs", tmp_path / "lake"
    assert sweep(out, lake, "--worlds", 2, "--steps", 40).exit_code == 0
    assert json.loads((out / "study.json").read_text())["terms"]["lr_decay_steps"] == 32
    result = sweep(out, lake, "--worlds", 3, "--steps", 60)
    assert result.exit_code == 0, result.stderr
    assert "extending the study" in result.stderr and "from 40 to 60 steps" in result.stderr
    runs = sorted(p for p in out.iterdir() if p.is_dir())
    assert [p.name for p in runs] == [f"grid-seed{w}-MM-nh3-seed{w}" for w in (4, 5, 6)]
    assert [(config_of(p)["steps"], config_of(p)["lr_decay_steps"]) for p in runs] == [(60, 32)] * 3
    assert [len(config_of(p)["extensions"]) for p in runs] == [1, 1, 0]
    assert all(RunView.open(p).metrics()[-1]["step"] == 60 for p in runs)
    report = smtrain("report", *runs, "--out", tmp_path / "report")
    assert report.exit_code == 0, report.stderr
    assert "| grid | 3 | MM | 3 | 60 |" in (tmp_path / "report" / "final.md").read_text()  # one study of 3 runs


def test_a_study_with_other_terms_is_refused_before_anything_is_generated(tmp_path):
    out, lake = tmp_path / "runs", tmp_path / "lake"
    assert sweep(out, lake, "--worlds", 1, "--steps", 40).exit_code == 0
    before = sorted(p.name for p in lake.iterdir())
    line = error_line(sweep(out, lake, "--worlds", 2, "--steps", 40, "--nh", 5))
    assert "holds a study with other terms" in line and "n_h 3 (asked 5)" in line
    line = error_line(sweep(out, lake, "--worlds", 2, "--steps", 60, "--lr-decay-steps", 50))
    assert "lr_decay_steps 32 (asked 50)" in line
    line = error_line(sweep(out, lake, "--worlds", 2, "--steps", 20))
    assert "--steps 20 is fewer than the 40 steps of the study" in line
    assert sorted(p.name for p in lake.iterdir()) == before  # world 5 was never generated
    assert sorted(p.name for p in out.iterdir()) == ["grid-seed4-MM-nh3-seed4", "study.json"]


def test_one_comparison_judges_every_record():
    """common/differing.py: a key missing on one side differs, unless the older record never held it."""
    from smspace.common.differing import described, differing
    from smspace.train.terms import grown

    assert differing({"a": 1, "b": 2}, {"a": 1, "b": 3, "c": 4}) == ["b", "c"]
    assert differing({"a": 1, "b": 2}, {"a": 1, "b": 3, "c": 4}, within={"a", "c"}) == ["c"]
    assert differing({"a": 1, "b": 2}, {"a": 2, "b": 3}, ignore=("b",)) == ["a"]
    assert described({"n": 3, "m": "x"}, {"n": 4, "m": "x"}, prefix="train.") == ["train.n 3 -> 4"]
    assert described({"w": None}, {"w": [1]}) == ["w (unset) -> [1]"]
    assert grown(100, 100, "never") is None and grown(100, 150, "never") == {"from_steps": 100, "to_steps": 150}
    with pytest.raises(SmspaceError, match=r"^a run is never shortened$"):
        grown(100, 50, "a run is never shortened")
