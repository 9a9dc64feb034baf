"""A researcher's own setup or network is held to the contract smspace's own are (docs/API.md,
"Plugins"): checked on a probe batch before anything is written, each break one line naming the
plugin and its entry point, and whatever a plugin raises reported as raised. The bad plugins are
tests/plugins/smspace_bad_plugins (one break each), put on the path here, not installed."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from .conftest import SAMPLES, failed_in_one_line, run_cmd, short_fit

PLUGINS = Path(__file__).parent / "plugins"


@pytest.fixture(scope="module", autouse=True)
def bad_plugins():
    """The bad plugins' folder on sys.path for this process and PYTHONPATH for its children."""
    from smspace.common import plugins

    sys.path.insert(0, str(PLUGINS))
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(PLUGINS), old) if p)
    plugins.registered.cache_clear()
    plugins.others.cache_clear()
    yield
    sys.path.remove(str(PLUGINS))
    if old is None:
        os.environ.pop("PYTHONPATH")
    else:
        os.environ["PYTHONPATH"] = old
    plugins.registered.cache_clear()
    plugins.others.cache_clear()


one_error_line = failed_in_one_line


@pytest.fixture(scope="module")
def tiny_lake(tmp_path_factory) -> Path:
    lake = tmp_path_factory.mktemp("tiny")
    result = run_cmd("smgen", "generate", "--setup", "tiny", "--mode", "MM", "--transitions", 3000, "--lake", lake)
    assert result.returncode == 0, result.stderr
    return lake


def fit(lake: Path, out: Path, *extra):
    return short_fit("tiny-seed0-MM", lake, out, *extra)


@pytest.mark.parametrize(
    "model, needle",
    [
        ("broadcast", "gave shape (7, 1) on a probe batch of 7; it must give exactly (B, N_s) = (7, 5)"),
        ("wideh", "encode(m) gave shape (7, 5) on a probe batch of 7; it must give exactly (B, N_h) = (7, 3)"),
        ("wideout", "forward(m_t, s_t, m_t1) gave shape (7, 6)"),
        ("refusing", "raised in its constructor: ValueError: RefusingNet needs at least 4 motors"),
        (
            "persample",
            "objective(m_t, s_t, m_t1, s_t1) gave shape (7,) on a probe batch of 7; it must give exactly a scalar",
        ),
        ("detached", "its training loss does not depend on any trainable parameter"),
        ("paramstep", "after_step() changed parameter encoder.weight; it may change only buffers"),
        ("manynoise", "noise_dim must be an int in 0..4096, not 'many'"),
    ],
)
def test_a_model_that_breaks_the_contract_is_refused_before_a_run_folder_is_written(tiny_lake, tmp_path, model, needle):
    out = tmp_path / "run"
    line = one_error_line(fit(tiny_lake, out, "--model", model))
    assert f"model {model!r} (smspace_bad_plugins:" in line and needle in line, line
    assert not out.exists()


def test_an_error_inside_a_plugin_constructor_is_reported_as_raised(tiny_lake, tmp_path):
    out = tmp_path / "run"
    line = one_error_line(fit(tiny_lake, out, "--model", "typed", "--model-params", '{"width": "32"}'))
    assert "model 'typed' (smspace_bad_plugins:TypedNet) raised in its constructor: TypeError: " in line, line
    assert "does not take these parameters" not in line and not out.exists()
    taken = fit(tiny_lake, tmp_path / "ok", "--model", "typed", "--model-params", '{"width": 4}')
    assert taken.returncode == 0, taken.stderr
    refused = one_error_line(fit(tiny_lake, tmp_path / "r", "--model", "typed", "--model-params", '{"depth": 4}'))
    assert "does not take these parameters" in refused


def test_a_bad_model_is_refused_by_a_sweep_and_its_dry_run_before_anything_is_written(tmp_path):
    lake, out = tmp_path / "lake", tmp_path / "runs"
    study = tmp_path / "study.toml"
    study.write_text('[study]\nname = "bad"\nsetup = "tiny"\nmodes = ["MM"]\nworlds = 2\ntransitions = 3000\n'
                     '[train]\nmodel = "broadcast"\nsteps = 40\neval_every = 20\n')  # fmt: skip
    for dry in (["--dry-run"], []):
        line = one_error_line(run_cmd("smtrain", "sweep", study, "--lake", lake, "--out", out, *dry))
        assert "model 'broadcast'" in line and "no broadcasting" in line, line
        assert not out.exists() and not lake.exists()
    flags = ["--setup", "tiny", "--modes", "MM", "--worlds", 1, "--transitions", 3000, "--steps", 40,
             "--eval-every", 20, "--lake", lake, "--out", out, "--workers", 1]  # fmt: skip
    line = one_error_line(run_cmd("smtrain", "sweep", *flags, "--model", "refusing"))
    assert "ValueError: RefusingNet needs at least 4 motors" in line
    assert not out.exists() and not lake.exists()


@pytest.mark.parametrize(
    "setup, needle",
    [
        ("nanworld", "s_t holds 64 non-finite value(s)"),
        ("shortsense", "s_t has shape (64, 4); the world declares (64, 5)"),
        ("widemotors", "motor states must lie in [-1, 1]"),
        ("brokenbuild", "raised building world 0: ValueError: room 0 has no floor"),
    ],
)
def test_a_setup_that_breaks_the_contract_is_refused_before_anything_is_written(tmp_path, setup, needle):
    lake = tmp_path / "lake"
    line = one_error_line(run_cmd("smgen", "generate", "--setup", setup, "--mode", "all", "--transitions", 3000,
                                  "--lake", lake))  # fmt: skip
    assert f"setup {setup!r} (smspace_bad_plugins:" in line and needle in line, line
    assert not lake.exists() or not any(lake.glob(f"{setup}-*")), sorted(lake.rglob("*"))


@pytest.mark.parametrize(
    "setup, needle",
    [
        ("tiny", "cannot walk: its world, TinyWorld, has no walk_motors"),
        ("widewalk", "motor states must lie in [-1, 1]"),
    ],
)
def test_a_setup_that_cannot_walk_is_refused_before_anything_is_written(tmp_path, setup, needle):
    lake = tmp_path / "lake"
    line = one_error_line(run_cmd("smgen", "generate", "--setup", setup, "--mode", "MME", "--transitions", 3000,
                                  "--exploration", "walk", "--walk-length", 10, "--lake", lake))  # fmt: skip
    assert f"setup {setup!r} (smspace_bad_plugins:" in line and needle in line, line
    assert not lake.exists() or not any(lake.glob(f"{setup}-*")), sorted(lake.rglob("*"))


def test_a_nan_drawn_late_is_refused_before_its_part_is_committed(tmp_path):
    """The probe batch passes; a later part holds a NaN: nothing of it is stored, nothing is called
    written, and the lake reads as before (no dataset, no "corrupt manifest" anywhere)."""
    lake = tmp_path / "lake"
    result = run_cmd("smgen", "generate", "--setup", "latenan", "--mode", "MM", "--transitions", 6000,
                     "--shard-size", 2000, "--lake", lake, "--workers", 1)  # fmt: skip
    line = one_error_line(result)
    assert "setup 'latenan'" in line and "non-finite" in line and "nothing was committed" in line, line
    assert "written" not in result.stdout
    folder = lake / "latenan-seed0-MM"
    assert not (folder / "manifest.json").exists()
    stored = sorted(p.name for p in folder.glob("shard-*.mcap"))
    assert stored == ["shard-00000.mcap"], stored  # the part drawing the NaN (shard 1) was never stored
    assert "shard-00001.mcap" in line
    listed = run_cmd("smgen", "ls", "--lake", lake)
    assert listed.returncode == 0 and "corrupt" not in listed.stdout + listed.stderr, listed


def test_plugins_are_recorded_and_a_changed_plugin_is_a_changed_config(tmp_path, tiny_lake):
    manifest = json.loads((tiny_lake / "tiny-seed0-MM" / "manifest.json").read_text())
    plugin = manifest["config"]["plugin"]
    assert plugin["entry_point"] == "smspace_bad_plugins:TINY" and plugin["distribution"] == "smspace-bad-plugins"
    assert plugin["version"] == "0.1.0" and len(plugin["code_sha256"]) == 16
    out = tmp_path / "run"
    assert fit(tiny_lake, out, "--model", "typed").returncode == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["model_plugin"]["entry_point"] == "smspace_bad_plugins:TypedNet"
    assert cfg["model_plugin"]["code_sha256"] == plugin["code_sha256"]  # one package, one hash

    # the plugin's code changes: the dataset is another config, the run another model
    changed = tmp_path / "changed"
    import shutil

    shutil.copytree(PLUGINS, changed)
    source = changed / "smspace_bad_plugins" / "__init__.py"
    source.write_text(source.read_text() + "\nCHANGED = True\n")
    env = {"PYTHONPATH": str(changed)}
    again = run_cmd("smgen", "generate", "--setup", "tiny", "--mode", "MM", "--transitions", 3000,
                    "--lake", tiny_lake, env=env)  # fmt: skip
    line = one_error_line(again)
    assert "generated with another config (plugin code_sha256 " in line and "--overwrite" in line, line
    resumed = run_cmd("smtrain", "fit", "--resume", out, "--steps", 60, env=env)
    line = one_error_line(resumed)
    assert "model 'typed' changed since" in line and "code_sha256" in line, line


def test_a_grid_over_precisions_that_resolve_alike_is_refused_before_anything_is_written(tmp_path):
    """`precision = ["fp32", "auto"]` where auto keeps fp32: duplicate runs the report later refused."""
    from smspace.train.precision import resolve

    decided = resolve("auto", "cpu")[0]
    study = tmp_path / "study.toml"
    study.write_text(f'[study]\nsetup = "grid"\nmodes = ["MM"]\nworlds = 1\ntransitions = 3000\n[train]\nsteps = 20\n'
                     f'eval_every = 10\n[grid]\nprecision = ["{decided}", "auto"]\n')  # fmt: skip
    for dry in (["--dry-run"], []):
        result = run_cmd("smtrain", "sweep", study, "--lake", tmp_path / "lake", "--out", tmp_path / "runs", *dry)
        line = one_error_line(result)
        assert f"precision={decided} and precision=auto train the same runs" in line, line
        assert f"both train in {decided} here" in line
        assert not (tmp_path / "runs").exists() and not (tmp_path / "lake").exists()


def test_what_was_asked_and_what_was_done_are_recorded(tmp_path):
    """--precision auto records what it was decided as and that auto was asked; --compile that
    fell back to eager records the fallback in the session, and says it in one whole sentence."""
    out = tmp_path / "run"
    args = ["fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 20, "--eval-every", 10]
    env = {"CXX": "/bin/false", "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}
    result = run_cmd("smtrain", *args, "--precision", "auto", "--compile", env=env, timeout=600)
    assert result.returncode == 0, result.stderr
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["precision_asked"] == "auto" and cfg["precision"] in ("fp32", "bf16")
    (session,) = cfg["sessions"]
    assert session["compile"].startswith("eager: torch.compile does not work here (") and cfg["compile"] == "on"
    (line,) = [ln for ln in result.stderr.splitlines() if ln.startswith("--compile:")]
    assert line.endswith("; training eagerly (recorded in config.json)"), line
    info = run_cmd("smtrain", "info", out)
    assert "eager: torch.compile does not work here" in info.stdout, info.stdout


def test_a_plugin_named_like_a_builtin_is_said_and_one_exiting_at_import_is_one_line(tiny_lake, tmp_path):
    """A setup registered as `grid` was ignored without a word; a plugin calling sys.exit(7) at
    import ended the command silently with 7."""
    env = {"PYTHONPATH": os.pathsep.join([str(PLUGINS.parent / "plugins-shadow"), str(PLUGINS)])}
    listed = run_cmd("smgen", "ls", "--lake", tiny_lake, env=env)
    assert listed.returncode == 0, listed.stderr
    notes = [ln for ln in listed.stderr.splitlines() if "is not used" in ln]
    assert notes == [
        "smspace: note: the setup 'grid' of smspace-shadow-plugins (smspace_shadow_plugins:GRID) is not used: "
        "smspace's own setup has that name; register it under another"
    ], listed.stderr
    result = run_cmd("smtrain", "fit", "tiny-seed0-MM", "--lake", tiny_lake, "--out", tmp_path / "r", "--model",
                     "exiting", env=env)  # fmt: skip
    line = one_error_line(result)
    assert "model 'exiting' (smspace_shadow_plugins.exiting:Net) raised being imported: SystemExit: 7" in line, line
    assert not (tmp_path / "r").exists()
