"""--precision and --compile (train/precision.py): recorded, kept on resume, part of a study's
terms; a compiler that does not work is one line, then eager training."""

from __future__ import annotations

import json

import pytest

from smspace.train.precision import resolve
from smspace.train.run_dir import RunDir, RunView

from .conftest import SAMPLES, run_cmd, smtrain


def test_auto_is_decided_when_the_run_is_created_and_kept_on_resume(tmp_path):
    out = tmp_path / "run"
    args = ["grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 40, "--eval-every", 20]
    result = run_cmd("smtrain", "fit", *args, "--precision", "auto")
    assert result.returncode == 0, result.stderr
    decided, why = resolve("auto", "cpu")
    assert f"--precision auto: {decided} ({why})" in result.stderr
    assert RunView.open(out).config.precision == decided  # what was decided, never "auto"
    refused = smtrain("fit", "--resume", out, "--steps", 60, "--precision", "fp32" if decided == "bf16" else "bf16")
    assert refused.exit_code == 2 and "--precision" in refused.output
    assert smtrain("fit", "--resume", out, "--steps", 60).exit_code == 0
    assert RunView.open(out).config.precision == decided


def test_bf16_trains_in_bf16_and_is_a_term_of_its_study(tmp_path):
    lake, out = tmp_path / "lake", tmp_path / "runs"
    sweep = ["sweep", "--setup", "grid", "--modes", "MM", "--worlds", 2, "--transitions", 2500, "--steps", 40,
             "--eval-every", 20, "--lake", lake, "--out", out, "--workers", 1]  # fmt: skip
    assert smtrain(*sweep, "--precision", "bf16").exit_code == 0
    runs = [RunDir.open(p.parent) for p in sorted(out.glob("*/config.json"))]
    assert len(runs) == 2 and all(r.view.config.precision == "bf16" for r in runs)
    alone = smtrain("fit", "grid-seed0-MM", "--lake", lake, "--out", tmp_path / "fp32", "--steps", 40,
                    "--eval-every", 20)  # fmt: skip
    assert alone.exit_code == 0
    in_bf16 = runs[0].view.metrics()[-1]["eval_loss"]
    in_fp32 = RunView.open(tmp_path / "fp32").metrics()[-1]["eval_loss"]
    assert in_bf16 != in_fp32 and in_bf16 == pytest.approx(in_fp32, rel=0.2)  # rounded, not another model
    refused = smtrain(*sweep, "--precision", "fp32")
    assert refused.exit_code == 2 and 'precision "bf16" (asked "fp32")' in refused.output


def test_compile_reports_its_time_and_a_broken_compiler_falls_back_in_one_line(tmp_path):
    args = ["grid-seed0-MM", "--lake", SAMPLES, "--steps", 30, "--eval-every", 10, "--compile"]
    env = {"SMSPACE_PROGRESS_EVERY": "0.01", "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}
    no_compiler = env | {"CXX": "/bin/false"}
    broken = run_cmd("smtrain", "fit", *args, "--out", tmp_path / "broken", env=no_compiler, timeout=600)
    assert broken.returncode == 0, broken.stderr
    fallback = [ln for ln in broken.stderr.splitlines() if ln.startswith("--compile:")]
    assert len(fallback) == 1 and "does not work here" in fallback[0] and "training eagerly" in fallback[0]
    assert json.loads((tmp_path / "broken" / "status.json").read_text())["state"] == "finished"

    works = run_cmd("smtrain", "fit", *args, "--out", tmp_path / "compiled", env=env, timeout=600)
    assert works.returncode == 0, works.stderr
    assert "--compile:" not in works.stderr and any("compiled in " in ln for ln in works.stderr.splitlines())
    compiled, eager = RunView.open(tmp_path / "compiled").metrics(), RunView.open(tmp_path / "broken").metrics()
    for a, b in zip(compiled, eager, strict=True):  # fused kernels sum in another order: the same run, to rounding
        assert a["eval_loss"] == pytest.approx(b["eval_loss"], rel=1e-3), (a, b)


def test_a_sweep_without_a_compiler_says_so_once_not_once_per_worker(tmp_path):
    """A --compile sweep on a machine without a working compiler printed its line once per worker."""
    sweep = ["sweep", "--setup", "grid", "--modes", "MM,MME", "--worlds", 1, "--transitions", 2500, "--steps", 20,
             "--eval-every", 10, "--lake", tmp_path / "lake", "--out", tmp_path / "runs", "--workers", 2,
             "--compile"]  # fmt: skip
    env = {"CXX": "/bin/false", "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}
    result = run_cmd("smtrain", *sweep, env=env, timeout=600)
    assert result.returncode == 0, result.stderr
    fallback = [ln for ln in result.stderr.splitlines() if ln.startswith("--compile:")]
    assert len(fallback) == 1 and "training eagerly" in fallback[0], result.stderr
    sessions = [RunView.open(p.parent).config.sessions[-1] for p in (tmp_path / "runs").glob("*/config.json")]
    assert len(sessions) == 2 and all(s["compile"].startswith("eager:") for s in sessions), sessions


def test_compile_auto_compiles_where_the_sessions_run_steps_repay_it_and_records_why(tmp_path, monkeypatch):
    """--compile auto decides per session on what it will train (steps left x runs trained
    together): a short session trains eagerly without even probing the compiler, a long one
    compiles, and each session records what it did and why."""
    from smspace.train import precision

    probed, cache = [], {"warm": False}
    monkeypatch.setattr(precision, "_compile_problem", lambda: probed.append(1))
    monkeypatch.setattr(precision, "_inductor_cache_warm", lambda: cache["warm"])
    warm_from, cold_from = precision.AUTO_COMPILE_RUN_STEPS_WARM, precision.AUTO_COMPILE_RUN_STEPS
    short = precision.compile_decision("auto", warm_from - 1)
    assert short.startswith("eager: auto") and not precision.compiles(short) and not probed
    cold = precision.compile_decision("auto", cold_from - 1)
    assert cold.startswith("eager: auto") and "empty inductor cache" in cold and not probed
    long = precision.compile_decision("auto", cold_from)
    assert precision.compiles(long) and "auto" in long and "empty inductor cache" in long and probed
    cache["warm"] = True  # a session here compiled before: its graphs are read, not compiled again
    warm = precision.compile_decision("auto", warm_from)
    assert precision.compiles(warm) and "warm inductor cache" in warm
    assert precision.compile_decision("off", 10**9) is None
    assert precision.compile_decision("on", 1) == "torch.compile"  # asked for: compiled however short

    out = tmp_path / "run"
    args = ["grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 30, "--eval-every", 10, "--compile", "auto"]
    result = run_cmd("smtrain", "fit", *args)
    assert result.returncode == 0, result.stderr
    config = RunView.open(out).config
    assert config.compile == "auto"
    assert config.sessions[-1]["compile"].startswith("eager: auto, 30 run-steps"), config.sessions
    assert smtrain("fit", "--resume", out, "--steps", 50).exit_code == 0  # the session trains the 20 steps left
    assert RunView.open(out).config.sessions[-1]["compile"].startswith("eager: auto, 20 run-steps")


def test_compile_keeps_reading_the_true_and_false_of_older_runs_and_study_files(tmp_path):
    from smspace.study.file import parse_study
    from smspace.train.config import TrainConfig

    assert TrainConfig(dataset="d", compile=True).compile == "on"
    assert TrainConfig.from_dict({"dataset": "d", "compile": False}).compile == "off"
    with pytest.raises(Exception, match="--compile 'sometimes': one of off, on, auto"):
        TrainConfig(dataset="d", compile="sometimes")
    study = {"study": {"name": "s", "setup": "grid", "modes": ["MM"], "worlds": 1}}
    for given, kept in ((True, "on"), (False, "off"), ("auto", "auto")):
        parsed = parse_study({**study, "train": {"steps": 20, "compile": given}}, "study.toml", default_name="s")
        assert parsed.train["compile"] == kept
    with pytest.raises(Exception, match=r"train\.compile"):
        parse_study({**study, "train": {"steps": 20, "compile": 1}}, "study.toml", default_name="s")
    bad = smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", tmp_path / "x", "--compile", "always")
    assert bad.exit_code == 2 and "'always' is not one of 'off', 'on', 'auto'" in bad.output


def test_a_warm_inductor_cache_is_one_that_holds_compiled_graphs(tmp_path, monkeypatch):
    from smspace.train.precision import _inductor_cache_warm

    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "inductor"))
    assert not _inductor_cache_warm()
    (tmp_path / "inductor" / "fxgraph").mkdir(parents=True)
    assert not _inductor_cache_warm()
    (tmp_path / "inductor" / "fxgraph" / "ab").mkdir()
    assert _inductor_cache_warm()
