"""A leaderboard nobody can fool (issue 41): a collapsed h is never scored, every result proves its
scores from the evidence it carries, an entry has one canonical name and folder, and every value a
page shows is escaped. The forgeries are edits of a real tiny bench's results; each must be
refused in one line naming the file, and the honest results must give the exact table."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from smspace.bench import evidence
from smspace.bench.cli import parse_entry
from smspace.bench.leaderboard import escape, markdown, row_names
from smspace.bench.result import ScoredRow
from smspace.bench.suite import SUITES
from smspace.bench.verify import Result
from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.metrics.scores import scores_of
from smspace.metrics.significance import bootstrap_interval, paired_p, seed_of
from smspace.metrics.spatial import DegenerateRepresentation, check_representation, spatial_scores

from .conftest import SAMPLES, failed_in_one_line, run_cmd

PLUGINS = Path(__file__).parent / "plugins"
SHALLOW = "tiny-v1/shallow/grid"


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    """tiny@1 with a plugin's model and isomap, and tiny@2's one-world task grid6 with isomap."""
    root = tmp_path_factory.mktemp("proof")
    lake, out = root / "lake", root / "out"
    done = run_cmd("smtrain", "bench", "tiny@1", "shallow", "isomap", "--lake", lake, "--out", out, "--workers", 1,
                   timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    more = run_cmd("smtrain", "bench", "tiny@2", "isomap", "--task", "grid6", "--lake", lake, "--out", out,
                   "--workers", 1, timeout=600)  # fmt: skip
    assert more.returncode == 0, more.stderr
    return root


one_line = failed_in_one_line


def board(*paths, out: Path):
    return run_cmd("smtrain", "leaderboard", *paths, "--out", out)


def copied(bench: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "copy"
    shutil.copytree(bench / "out", copy)
    return copy


def edit(path: Path, change: Callable[[Any], Any]) -> None:
    """The file's JSON changed in place by `change`, or replaced by what it returns if `replaced`."""
    data = json.loads(path.read_text())
    changed = change(data)
    path.write_text(json.dumps(changed if getattr(change, "replaces", False) else data))


def replaced(change: Callable[[Any], Any]) -> Callable[[Any], Any]:
    change.replaces = True  # type: ignore[attr-defined]
    return change


def set_row(key: str, value: Any, row: int = 0) -> Callable[[dict], None]:
    def change(scores: dict) -> None:
        scores["rows"][row][key] = value

    return change


# --- 1. a degenerate h is a refusal, never a score ------------------------------------------------


def test_a_collapsed_or_non_finite_h_is_refused_by_every_score():
    _, p = Dataset.open(SAMPLES / "grid-seed0-MM").regular_sampling()
    good = np.c_[p, p[:, :1] ** 2] + 0.01
    assert np.isfinite(scores_of(good, p, 0)["d_topo"])
    nan = good.copy()
    nan[3, 1] = np.nan
    two = np.where(np.arange(len(p))[:, None] % 2 == 0, 1.0, 2.0) * np.ones((len(p), 3))
    for bad, said in [(np.ones_like(good), "collapsed: 1 distinct"), (nan, "1 non-finite"), (two, "2 distinct")]:
        for score in (check_representation, lambda h: spatial_scores(h, p), lambda h: scores_of(h, p, 0)):
            with pytest.raises(DegenerateRepresentation, match=said):
                score(bad)


@pytest.fixture
def bad_plugins(monkeypatch):
    """tests/plugins/smspace_bad_plugins on the path of this process and its children."""
    from smspace.common import plugins

    monkeypatch.syspath_prepend(str(PLUGINS))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGINS), os.environ.get("PYTHONPATH")])))
    plugins.registered.cache_clear()
    plugins.others.cache_clear()
    yield
    plugins.registered.cache_clear()
    plugins.others.cache_clear()


def test_a_model_whose_h_collapses_fails_its_run_in_one_line_with_no_score(bench, tmp_path, bad_plugins):
    out = tmp_path / "out"
    done = run_cmd("smtrain", "bench", "tiny@1", "constanth", "--lake", bench / "lake", "--out", out, "--workers", 1,
                   timeout=600)  # fmt: skip
    line = one_line(done)
    assert "collapsed: 1 distinct value(s)" in line and "no score is computed from it" in line, line
    folder = out / "tiny-v1/constanth/grid"
    assert not (folder / "scores.json").exists()
    sessions = json.loads((folder / "bench.json").read_text())["sessions"]
    assert [s["outcome"] for s in sessions] == ["failed"] and sessions[0]["wall_s"] >= 0
    shown = board(out, out=tmp_path / "b")
    assert "no result to show" in one_line(shown) and "its sessions failed" in shown.stderr, shown.stderr


# --- 2. a result proves itself --------------------------------------------------------------------


def test_honest_results_give_the_exact_table(bench, tmp_path):
    done = board(bench / "out", out=tmp_path / "b")
    assert done.returncode == 0, done.stderr
    table = json.loads((tmp_path / "b/leaderboard.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    cells = {(c["entry"], c["task"], c["mode"], c["score"]): c for c in table["cells"]}
    for entry in ("shallow", "isomap"):
        rows = json.loads((bench / f"out/tiny-v1/{entry}/grid/scores.json").read_text())["rows"]
        for mode in ("MM", "MME"):
            values = np.array([r["d_metric"] for r in rows if r["mode"] == mode])
            cell = cells[(entry, "grid", mode, "d_metric")]
            assert cell["mean"] == values.mean() and cell["std"] == values.std(ddof=1), cell
    assert cells[("isomap", "grid6", "MM", "d_topo")]["std"] is None  # one world: no spread, valid JSON
    assert cells[("isomap", "grid6", "MM", "d_topo")]["ci"] is None
    assert table["differences"]["bootstrap_seed"] == 0
    for (entry, task, mode, score), cell in cells.items():  # every interval and test follows from the cells
        if cell["ci"] is not None:
            seed = seed_of(0, "tiny", task, mode, score, entry)
            assert cell["ci"] == list(bootstrap_interval(cell["values"], seed)), cell
        if cell["vs_best"] is not None:
            best = cells[(cell["vs_best"]["entry"], task, mode, score)]
            assert best["is_best"] and cell["vs_best"]["p"] == paired_p(cell["values"], best["values"]), cell


def _rehash(folder: Path, row: int, h: np.ndarray) -> Callable[[dict], None]:
    """Evidence replaced by `h`, its hash made to match (what a careful forger does)."""
    scores = json.loads((folder / "scores.json").read_text())
    name = scores["rows"][row]["h"]
    data = evidence.npy_bytes(h)
    (folder / "evidence" / name).write_bytes(data)
    return set_row("h_sha256", evidence.sha256(data), row)


FORGERIES: dict[str, tuple[str, Callable[[dict], Any], str]] = {
    # name: (file, edit, what the refusal says)
    "tiny d_metric": ("scores", set_row("d_metric", 1e-9), "does not follow from its evidence: d_metric 1e-09"),
    "negative score": ("scores", set_row("d_topo", -0.1), "has d_topo -0.1, not a number it can take"),
    "R² of 3": ("scores", set_row("probe_r2", 3.0), "has probe_r2 3.0"),
    "string score": ("scores", set_row("d_topo", "0.001"), "has d_topo '0.001'"),
    "boolean score": ("scores", set_row("local_dim", True), "has local_dim True"),
    "null score": ("scores", set_row("d_metric", None), "has d_metric None"),
    "list score": ("scores", set_row("d_metric", [0.1]), "has d_metric [0.1]"),
    "missing score": ("scores", lambda s: s["rows"][0].pop("probe_r2"), "has probe_r2 None"),
    "step 1": ("scores", set_row("step", 1), "scored at step 1, not the protocol's 60"),
    "world twice": ("scores", set_row("world", 1, row=0), "or one counted twice"),
    "world not the task's": ("scores", set_row("world", 7), "world 7, mode 'MM': not one of"),
    "world a string": ("scores", set_row("world", "abc"), "world 'abc'"),
    "mode a list": ("scores", set_row("mode", ["MM"]), "mode ['MM']"),
    "MM rows pooled with MME": ("scores", lambda s: [r.update(mode="MM") for r in s["rows"]], "counted twice"),
    "a row fewer": ("scores", lambda s: s["rows"].pop(), "3 scored runs, where task grid has 2 worlds x 2 modes"),
    "rows a string": ("scores", lambda s: s.update(rows="all"), "'all' scored runs"),
    "negative wall time": ("scores", set_row("wall_s", -5), "has wall_s -5"),
    "wall time a string": ("scores", set_row("wall_s", "5"), "has wall_s '5'"),
    "no evidence named": ("scores", lambda s: s["rows"][0].pop("h"), "names no evidence"),
    "evidence of another file": ("scores", set_row("h_sha256", "0" * 64), "its sha256 differs"),
    "scores of another code": ("scores", lambda s: s["entry"]["plugin"].update(code_sha256="f" * 16), "or code"),
    "sessions empty": ("bench", lambda b: b.update(sessions=[]), "sessions is [], not a list"),
    "session wall time negative": ("bench", lambda b: b["sessions"][0].update(wall_s=-1.0), "has wall_s -1.0"),
    "session wall time a list": ("bench", lambda b: b["sessions"][0].update(wall_s=[1]), "has wall_s [1]"),
    "forged dataset hash": ("bench", lambda b: b["datasets"].update({"grid-seed0-MM": "0" * 16}), "config hashes"),
    "datasets missing": ("bench", lambda b: b.pop("datasets"), "datasets is None, not a table of dataset ids"),
    "plugin code not a hash": ("bench", lambda b: b["entry"]["plugin"].update(code_sha256="forged!"), "not a hash"),
    "params a list": ("bench", lambda b: b["entry"].update(params=[1, 2]), "parameters are a table"),
    "params a string": ("bench", lambda b: b["entry"].update(params="width=64"), "parameters are a table"),
    "unknown suite": ("bench", lambda b: b.update(suite="nope"), "unknown suite 'nope'"),
    "unknown version": ("bench", lambda b: b.update(version=9), f"versions 1..{len(SUITES['tiny'])}, not '9'"),
    "version a string": ("bench", lambda b: b.update(version="1"), "version is '1', not a int"),
    "unknown task": ("bench", lambda b: b["task"].update(name="maze"), "has no task 'maze'"),
    "protocol key added": ("bench", lambda b: b["task"].update(extra=1), "(extra differ)"),
    "protocol steps": ("bench", lambda b: b["task"].update(steps=1), "(steps differ)"),
    "a trailing space": ("bench", lambda b: b["entry"].update(name="shallow "), "is not a plain name"),
    "a zero-width space": ("bench", lambda b: b["entry"].update(name="shal\u200blow"), "is not a plain name"),
    "a newline and pipes": ("bench", lambda b: b["entry"].update(name="x |\n| forged | 0 |"), "is not a plain name"),
    "html in the name": ("bench", lambda b: b["entry"].update(name="<script>alert(1)</script>"), "is not a plain name"),
    "learns a lie": ("bench", lambda b: b["entry"].update(learns=False), "learns, not as it says"),
    "a table, not a record": ("bench", replaced(lambda b: [b]), "is a list, not a table of fields"),
}


@pytest.mark.parametrize("name", list(FORGERIES))
def test_a_forged_result_is_refused_in_one_line_naming_its_file(bench, tmp_path, name):
    which, change, said = FORGERIES[name]
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    edit(folder / f"{which}.json", change)
    line = one_line(board(copy, out=tmp_path / "b"))
    assert str(folder) in line and said in line, line
    assert not (tmp_path / "b").exists()


def test_forged_evidence_is_refused(bench, tmp_path):
    """h replaced (its hash made to match): the scores no longer follow; a constant or NaN h, or
    an h of another shape or a pickled object, is refused before any score is computed."""
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    p = evidence.positions("grid", 0)
    better = np.c_[p, np.zeros(len(p))]  # an h that is p itself: the best scores there are
    edit(folder / "scores.json", _rehash(folder, 0, better))
    assert "does not follow from its evidence" in one_line(board(copy, out=tmp_path / "b"))
    for h, said in [(np.ones((len(p), 3)), "collapsed"), (np.full((len(p), 3), np.nan), "non-finite"),
                    (np.ones((len(p), 4)), f"h of this task is ({len(p)}, 3)")]:  # fmt: skip
        edit(folder / "scores.json", _rehash(folder, 0, h))
        line = one_line(board(copy, out=tmp_path / "b"))
        assert said in line and "evidence/h-0-MM.npy" in line, line
    pickled = io.BytesIO()
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (folder / "evidence/h-0-MM.npy").write_bytes(pickled.getvalue())
    edit(folder / "scores.json", set_row("h_sha256", evidence.sha256(pickled.getvalue())))
    assert "holds a |O array" in one_line(board(copy, out=tmp_path / "b"))


def test_malformed_files_are_one_line_each(bench, tmp_path):
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    text = (folder / "scores.json").read_text()
    for forged, said in [
        (text.replace('"d_topo": ', '"d_topo": NaN, "x": ', 1), "NaN is not a JSON number"),
        (text.replace('"d_topo": ', '"d_topo": Infinity, "x": ', 1), "Infinity is not a JSON number"),
        (text.replace('"wall_s": ', '"wall_s": 1e999, "x": ', 1), "has wall_s inf"),
        ("[" * 200_000 + "]" * 200_000, "nested too deep"),
        ("{not json", "is not readable JSON"),
        (" " * (5 << 20), "bytes; a scores.json is at most"),
    ]:
        (folder / "scores.json").write_text(forged)
        line = one_line(board(copy, out=tmp_path / "b"))
        assert str(folder) in line and said in line, (said, line)


def test_a_result_of_the_layout_before_formats_is_read_and_another_format_refused(bench, tmp_path):
    """bench.json carried no format before lake/records.py: such a result gives the same table; a
    bench.json or scores.json of a format this smspace does not know is one line naming it."""
    assert board(bench / "out", out=tmp_path / "honest").returncode == 0
    copy = copied(bench, tmp_path)
    for found in copy.rglob("bench.json"):
        assert json.loads(found.read_text())["format"] == 1
        edit(found, lambda b: b.pop("format"))
    done = board(copy, out=tmp_path / "old")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "old/leaderboard.md").read_text() == (tmp_path / "honest/leaderboard.md").read_text()
    for name, value in [("bench.json", 99), ("bench.json", True), ("scores.json", 3), ("scores.json", "2")]:
        case = copied(bench, tmp_path / f"{name}-{value}")
        edit(case / SHALLOW / name, lambda r, v=value: r.update(format=v))
        line = one_line(board(case, out=tmp_path / "b"))
        assert f"{case / SHALLOW / name} is of format {value!r}; this smspace reads {name} of format" in line, line


def test_a_result_whose_scores_a_killed_or_failed_session_did_not_write_is_refused(bench, tmp_path):
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    edit(folder / "bench.json", lambda b: b["sessions"].append(b["sessions"][0] | {"wall_s": None, "outcome": None}))
    edit(folder / "scores.json", lambda s: s.update(session=1))
    assert "session 1, which it names, did not end" in one_line(board(copy, out=tmp_path / "b"))
    edit(folder / "scores.json", lambda s: s.update(session=5))
    assert "session 5 is not one of bench.json's 2" in one_line(board(copy, out=tmp_path / "b"))


def test_a_failed_session_counts_its_time_and_marks_nothing_incomplete(bench, tmp_path):
    copy = copied(bench, tmp_path)
    edit(copy / SHALLOW / "bench.json", lambda b: b["sessions"].append(b["sessions"][0] | {"outcome": "failed"}))
    assert board(copy, out=tmp_path / "b").returncode == 0
    assert "≥" not in (tmp_path / "b/leaderboard.md").read_text()
    killed = {"wall_s": None, "outcome": None}
    edit(copy / SHALLOW / "bench.json", lambda b: b["sessions"].append(b["sessions"][0] | killed))
    assert board(copy, out=tmp_path / "b").returncode == 0
    assert "| shallow | ≥ " in (tmp_path / "b/leaderboard.md").read_text()


# --- 3, 7, 28. scores are the code's that bench.json names ----------------------------------------


def test_overwrite_after_a_code_change_removes_the_old_scores_before_any_work(bench, tmp_path):
    """The entry's code changed: the result is refused naming both codes; --overwrite then removes
    the old scores and evidence at the session's start, so a session that fails leaves none."""
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    edit(folder / "bench.json", lambda b: b["entry"]["plugin"].update(code_sha256="0123456789abcdef"))
    edit(folder / "scores.json", lambda s: s["entry"]["plugin"].update(code_sha256="0123456789abcdef"))
    args = ["smtrain", "bench", "tiny@1", "shallow", "--lake", bench / "lake", "--out", copy, "--workers", 1]
    line = one_line(run_cmd(*args, timeout=600))
    assert "made with other code (code 0123456789abcdef, now " in line and "--overwrite replaces it" in line, line
    from smspace.bench.run import Entry, _begin
    from smspace.bench.suite import get_suite
    from smspace.lake.store import open_store

    suite = get_suite("tiny@1")  # the session --overwrite begins, before any work: the old scores are gone
    _begin(open_store(str(copy)).child("tiny-v1").child("shallow").child("grid"), suite, suite.tasks[0],
           Entry.of("shallow"), 1, "local", overwrite=True)  # fmt: skip
    assert not (folder / "scores.json").exists() and not list((folder / "evidence").iterdir())
    left = board(copy, out=tmp_path / "b")
    assert left.returncode == 0 and "its first session has not ended" in left.stderr, left.stderr
    assert "shallow" not in (tmp_path / "b/leaderboard.md").read_text()
    again = run_cmd(*args, timeout=600)  # the same terms now: it resumes, and scores anew
    assert again.returncode == 0, again.stderr
    assert board(copy, out=tmp_path / "b").returncode == 0
    assert "| shallow |" in (tmp_path / "b/leaderboard.md").read_text()


def test_a_row_is_one_code():
    def result(task: str, code: str) -> Result:
        return Result(f"out/{task}", "tiny", 2, task, "shallow", "shallow", code, 1.0, True, [])

    same = [result("grid", "a" * 16), result("grid6", "a" * 16)]
    assert set(row_names(same).values()) == {"shallow"}
    mixed = [result("grid", "a" * 16), result("grid6", "b" * 16)]
    assert set(row_names(mixed).values()) == {"shallow [code aaaaaaaaaaaa]", "shallow [code bbbbbbbbbbbb]"}


# --- 4, 6, 11, 16, 23. one canonical form per entry ------------------------------------------------


def test_look_alike_entries_are_one_entry_or_refused():
    assert parse_entry("contrastive:temperature=0.1") == parse_entry("contrastive")  # the default spelled out
    assert parse_entry("contrastive:embedding=64.0") == parse_entry("contrastive:embedding=64")
    assert parse_entry("contrastive:embedding=064").params == {"embedding": 64}
    assert parse_entry("contrastive:temperature=1").params == {"temperature": 1.0}
    for bad, said in [
        ("Sensorimotor", "unknown model 'Sensorimotor'"),
        ("sensorimotor ", "is not a plain name"),
        ("sensori\u200bmotor", "is not a plain name"),
        ("sensorimotor:width=64", "unknown parameter 'width' (it takes: none)"),
        ("contrastive:embedding=6.5", "is not a whole number"),
        ("contrastive:embedding=[1, 2]", "a list is not a int"),
        ("contrastive:temperature=x", "'x' is not a number"),
        ("contrastive:temperature=nan", "is not a finite number"),
        ("contrastive:embedding=1,embedding=2", "is given twice"),
        ('contrastive:temperature="0.1\x00"', "control or invisible characters"),
        ('contrastive:temperature="0.1\n"', "control or invisible characters"),
        ('contrastive:temperature="' + "1" * 300 + '"', "a value of 300 characters"),
        ("contrastive:temperature=[1", "an unclosed quote or bracket"),
    ]:
        with pytest.raises(SmspaceError, match=None) as caught:
            parse_entry(bad)
        assert said in str(caught.value), (bad, str(caught.value))


def test_lists_and_quoted_commas_are_values_and_folders_are_lossless():
    from smspace.bench.names import canonical_params, folder_of

    defaults = {"sizes": [8], "tag": 0.5, "note": "x"}
    params = canonical_params({"sizes": [1, 2], "tag": 0.1}, defaults, "entry")
    assert params == {"sizes": [1, 2], "tag": 0.1}
    assert folder_of("m", params) == "m,sizes=[1,2],tag=0.1" or folder_of("m", params).startswith("m,params-")
    close = canonical_params({"tag": 0.1000001}, defaults, "entry")
    assert folder_of("m", close) != folder_of("m", canonical_params({"tag": 0.1}, defaults, "entry"))
    text = canonical_params({"note": "a/b,c=d\u00a0e"}, defaults, "entry")  # NFKC: the no-break space is a space
    assert text == {"note": "a/b,c=d e"} and folder_of("m", text).startswith("m,params-")
    assert "/" not in folder_of("m", text) and "\n" not in folder_of("m", text)
    from smspace.bench.cli import _split_pairs

    assert _split_pairs('k=[1, 2],t="a,b",u=3', "spec") == ["k=[1, 2]", 't="a,b"', "u=3"]


def test_unknown_parameters_are_refused_before_anything_is_generated(tmp_path):
    args = ["--lake", tmp_path / "l", "--out", tmp_path / "o"]
    done = run_cmd("smtrain", "bench", "tiny", "sensorimotor:width=64", *args)
    assert "unknown parameter 'width'" in one_line(done)
    assert list(tmp_path.iterdir()) == []


def test_two_results_of_one_canonical_entry_are_refused(bench, tmp_path):
    copy = copied(bench, tmp_path)
    twin = copy / "tiny-v1/SHALLOW/grid"
    shutil.copytree(copy / SHALLOW, twin)
    for name in ("bench.json", "scores.json"):
        edit(twin / name, lambda d: d["entry"].update(name="SHALLOW"))
    line = one_line(board(copy, out=tmp_path / "b"))
    assert "two results of" in line and "on tiny task grid" in line and "not pooled" in line, line


def test_another_entrys_result_is_never_replaced(bench, tmp_path):
    """A folder holding another entry's result (an older smspace's lossy folder name, say) is refused
    with no hint to --overwrite, and --overwrite refuses too."""
    copy = copied(bench, tmp_path)
    edit(copy / "tiny-v1/isomap/grid/bench.json", lambda b: b["entry"].update(name="random-encoder", learns=True))
    args = ["smtrain", "bench", "tiny@1", "isomap", "--lake", bench / "lake", "--out", copy, "--workers", 1]
    for extra in ([], ["--overwrite"]):
        line = one_line(run_cmd(*args, *extra, timeout=600))
        assert "holds a result of another entry (random-encoder, not isomap)" in line, line
        assert "--overwrite never replaces another entry's result" in line
    assert (copy / "tiny-v1/isomap/grid/scores.json").exists()


# --- 5, 10, 22, 25, 29. what the leaderboard writes -----------------------------------------------


def test_every_value_a_page_shows_is_escaped():
    assert escape("a|b") == "a\\|b" and escape("<script>") == "&lt;script&gt;"
    assert escape("![x](http://e/i.png)") == "!\\[x\\](http://e/i.png)" and escape("## h") == "\\#\\# h"
    with pytest.raises(SmspaceError, match="line break"):
        escape("a\n| forged |")
    label = 'shallow (note="<b>|x")'
    result = Result("w", "tiny", 1, "grid", label, "s", "c", 1.0, True, [])
    scores = ("d_topo", "d_metric", "probe_r2", "local_dim")
    cells = [{"suite": "tiny", "version": 1, "task": "grid", "mode": "MM", "entry": label, "score": s, "mean": 0.5,
              "std": None} for s in scores]  # fmt: skip
    text = markdown(cells, [result], {"suite": "tiny", "versions": [1]})
    assert "<b>" not in text and "&lt;b&gt;\\|x" in text


def test_the_leaderboard_never_follows_a_planted_link_and_refuses_a_file_as_out(bench, tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("keep me")
    out = tmp_path / "b"
    out.mkdir()
    (out / "leaderboard.md").symlink_to(target)
    assert board(bench / "out", out=out).returncode == 0
    assert target.read_text() == "keep me" and not (out / "leaderboard.md").is_symlink()
    assert "is a file, not a folder" in one_line(board(bench / "out", out=target))


def test_a_link_or_fifo_for_a_results_file_is_refused_by_name(bench, tmp_path):
    copy = copied(bench, tmp_path)
    folder = copy / SHALLOW
    (folder / "scores.json").rename(tmp_path / "elsewhere.json")
    (folder / "scores.json").symlink_to(tmp_path / "elsewhere.json")
    line = one_line(board(copy, out=tmp_path / "b"))
    assert f"{folder}/scores.json" in line and "not a regular file" in line, line
    (folder / "bench.json").rename(tmp_path / "bench.json")
    os.mkfifo(folder / "bench.json")
    line = one_line(board(copy, out=tmp_path / "b"))
    assert f"{folder}/bench.json" in line and "not a regular file" in line, line


def test_only_failed_results_say_so_and_one_folder_given_twice_is_read_once(bench, tmp_path):
    copy = copied(bench, tmp_path)
    for folder in copy.glob("*/*/*"):
        (folder / "scores.json").unlink()
        edit(folder / "bench.json", lambda b: b["sessions"][0].update(outcome="failed"))
    done = board(copy, out=tmp_path / "b")
    assert "no result to show" in one_line(done) and "its sessions failed" in done.stderr
    twice = board(bench / "out", bench / "out", bench / "out/tiny-v1", out=tmp_path / "c")
    assert twice.returncode == 0, twice.stderr


def test_results_of_several_suites_get_a_leaderboard_each_in_its_folder(tmp_path, monkeypatch):
    from smspace.bench import leaderboard

    scores = {"d_metric": 0.2, "probe_r2": 0.5, "local_dim": 2.0}
    rows = [ScoredRow(w, "MM", 0, 1.0, "r", {"d_topo": 0.1 * (w + 1)} | scores, "h", "0" * 64) for w in range(2)]
    found = [
        Result(f"r/{suite}", suite, 1, "grid", "isomap", "isomap", "c", 1.0, True, rows)
        for suite in ("tiny", "spatial")
    ]
    monkeypatch.setattr(leaderboard, "find_results", lambda paths, left_out=None: found)
    written = leaderboard.write_leaderboard(["r"], tmp_path / "b")
    assert sorted(p.relative_to(tmp_path / "b").as_posix() for p in written if p.suffix == ".md") == [
        "spatial/leaderboard.md", "tiny/leaderboard.md"
    ]  # fmt: skip
    assert "# smspace-bench: spatial (v1)" in (tmp_path / "b/spatial/leaderboard.md").read_text()
    assert "## D_topo ↓ (lower: better)" in (tmp_path / "b/spatial/leaderboard.md").read_text()
    (tmp_path / "b/mine.txt").write_text("a file of the user's")
    monkeypatch.setattr(leaderboard, "find_results", lambda paths, left_out=None: found[1:])
    leaderboard.write_leaderboard(["r"], tmp_path / "b")  # one suite now: its pages at the top
    left = sorted(p.relative_to(tmp_path / "b").as_posix() for p in (tmp_path / "b").rglob("*.md"))
    assert left == ["leaderboard.md"], left  # tiny's and spatial's earlier pages are not left stale
    assert (tmp_path / "b/mine.txt").exists()  # what it did not write, it never removes


def test_the_leaderboard_writes_outside_the_results_it_reads(bench, tmp_path):
    copy = copied(bench, tmp_path)
    line = one_line(board(copy, out=copy / "tiny-v1" / "pages"))
    assert "lies inside" in line and "which it reads" in line, line
    assert not (copy / "tiny-v1" / "pages").exists()


def test_results_of_several_suites_get_a_leaderboard_each(bench, tmp_path):
    """The documented `smtrain leaderboard runs/bench docs/bench/results` (results of tiny and of
    spatial): a leaderboard per suite, in its own folder."""
    copy = copied(bench, tmp_path)
    (copy / "tiny-v2").rename(tmp_path / "tiny-v2")  # tiny@1 here, tiny@2 there: one suite still
    done = board(copy, tmp_path / "tiny-v2", out=tmp_path / "one")
    assert done.returncode == 0 and (tmp_path / "one/leaderboard.md").exists(), done.stderr
    other = tmp_path / "other"
    shutil.copytree(bench / "out/tiny-v1", other / "spatial-v1")
    for name in ("bench.json",):  # a result of another suite: its suite checked, then its protocol
        edit(other / "spatial-v1/isomap/grid" / name, lambda b: b.update(suite="spatial"))
    line = one_line(board(bench / "out", other / "spatial-v1/isomap", out=tmp_path / "two"))
    assert "measured under another protocol than spatial-v1 fixes" in line, line
    docs = Path(__file__).resolve().parents[1] / "docs/bench/results"  # the documented command
    both = board(bench / "out", docs, out=tmp_path / "three")
    assert both.returncode == 0, both.stderr
    made = sorted(p.relative_to(tmp_path / "three").as_posix() for p in (tmp_path / "three").rglob("*.md"))
    expected = ["leaderboard.md"] if "format 1" in both.stderr else ["spatial/leaderboard.md", "tiny/leaderboard.md"]
    assert made == expected, (made, both.stderr)


# --- 9, 17, 18, 19, 24. what the bench refuses, before it writes -----------------------------------


@pytest.mark.parametrize(
    "model, said",
    [
        ("randomop", "cannot be trained stacked"),
        ("itemnet", "cannot be trained stacked"),
        ("assignstep", "after_step() on a stacked copy did not update average as it does alone"),
        ("broadcast", "gave shape (7, 1) on a probe batch of 7"),
    ],
)
def test_a_model_that_cannot_run_as_the_bench_runs_it_is_refused_before_anything_is_written(
    bench, tmp_path, bad_plugins, model, said
):
    out = tmp_path / "out"
    line = one_line(run_cmd("smtrain", "bench", "tiny@1", model, "--lake", bench / "lake", "--out", out, timeout=600))
    assert said in line and f"model {model!r}" in line, line
    assert not out.exists()


@pytest.mark.parametrize(
    "model, said",
    [
        ("oddbatch", "forward(m_t, s_t, m_t1) gave shape (100, 1) on a batch of 100"),
        ("latedetach", "failed in training step"),
    ],
)
def test_a_model_that_breaks_later_fails_its_run_in_one_line(bench, tmp_path, bad_plugins, model, said):
    out = tmp_path / "out"
    args = ["smtrain", "bench", "tiny@1", model, "--lake", bench / "lake", "--out", out, "--workers", 1]
    line = one_line(run_cmd(*args, timeout=600))
    assert said in line, line
    assert not (out / f"tiny-v1/{model}/grid/scores.json").exists()


def test_a_random_op_model_still_trains_alone(tmp_path, bad_plugins):
    done = run_cmd("smtrain", "fit", SAMPLES / "grid-seed0-MM", "--model", "randomop", "--steps", 20,
                   "--eval-every", 10, "--out", tmp_path / "run", timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr


def test_the_bench_refuses_bad_folders_and_a_lake_of_another_suite(bench, tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    base = ["smtrain", "bench", "tiny@1", "isomap", "--workers", 1]
    refused = one_line(run_cmd(*base, "--lake", bench / "lake", "--out", a_file))
    assert f"--out {a_file} is a file" in refused, refused
    inside = one_line(run_cmd(*base, "--lake", bench / "lake", "--out", bench / "lake/results"))
    assert "must be apart" in inside
    other = tmp_path / "other-lake"
    made = run_cmd("smgen", "generate", "--setup", "grid", "--mode", "MM", "--seed", 0, "--transitions", 2500,
                   "--lake", other)  # fmt: skip
    assert made.returncode == 0, made.stderr
    line = one_line(run_cmd(*base, "--lake", other, "--out", tmp_path / "o", timeout=600))
    assert "give the suite a lake of its own (--lake)" in line and "--overwrite" not in line, line
    assert not (tmp_path / "o").exists()


def test_the_default_lake_is_the_suites_own(tmp_path):
    done = run_cmd("smtrain", "bench", "tiny@1", "isomap", "--dry-run", "--out", tmp_path / "o", "--workers", 1)
    assert done.returncode == 0, done.stderr
    assert " in data/bench-lake/tiny, " in done.stdout, done.stdout


def test_a_second_bench_into_the_same_folder_is_refused_while_the_first_writes(bench, tmp_path):
    from smspace.common.locks import hold_lock

    copy = copied(bench, tmp_path)
    held = hold_lock(copy / "tiny-v1/isomap/grid/bench.lock", "busy", wait=False)
    try:
        args = ["smtrain", "bench", "tiny@1", "isomap", "--lake", bench / "lake", "--out", copy, "--workers", 1]
        assert "another smtrain bench is writing" in one_line(run_cmd(*args, timeout=600))
    finally:
        held.release()
    sessions = json.loads((copy / "tiny-v1/isomap/grid/bench.json").read_text())["sessions"]
    assert len(sessions) == 1  # the refused bench recorded nothing


def test_a_resume_with_other_workers_is_refused(bench, tmp_path):
    copy = copied(bench, tmp_path)
    args = ["smtrain", "bench", "tiny@1", "shallow", "--lake", bench / "lake", "--out", copy]
    line = one_line(run_cmd(*args, "--workers", 2, timeout=600))
    assert "holds a result made with another workers" in line, line


def test_leftovers_of_killed_benches_are_removed_and_unseeded_numpy_is_seeded(tmp_path):
    import tempfile

    import torch

    from smspace.bench.run import remove_stale_temporaries
    from smspace.train.config import TrainConfig
    from smspace.train.engine import build

    dead = Path(tempfile.gettempdir()) / "smspace-bench-999999999-abc"
    alive = Path(tempfile.gettempdir()) / f"smspace-bench-{os.getpid()}-abc"
    for folder in (dead, alive):
        folder.mkdir(exist_ok=True)
    remove_stale_temporaries()
    assert not dead.exists() and alive.exists()
    alive.rmdir()
    cfg = TrainConfig(dataset=str(SAMPLES / "grid-seed0-MM"), seed=5)
    draws = []
    for _ in range(2):
        build(cfg, 2, 4, torch.device("cpu"))
        import random

        draws.append((np.random.rand(), random.random()))
    assert draws[0] == draws[1]


def test_isomap_is_bit_reproducible():
    from smspace.bench.representations import isomap_of_sensations

    ds = Dataset.open(SAMPLES / "grid-seed0-MM")
    first, second = (isomap_of_sensations(ds, 3, 0) for _ in range(2))
    assert first.tobytes() == second.tobytes()


def test_the_dry_run_says_when_the_cores_are_busy(monkeypatch):
    from smspace.bench import run

    monkeypatch.setattr(os, "getloadavg", lambda: (8.0 * (os.cpu_count() or 1), 0.0, 0.0))
    assert "the cores are busy" in run.busy_cores_note()[0]
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert run.busy_cores_note() == []


def test_the_api_takes_a_lake_object_or_a_path_alike():
    import smspace

    lake = smspace.open_lake(SAMPLES)
    by_object = smspace.TransitionStream("grid-seed0-MM", lake=lake)
    by_path = smspace.TransitionStream("grid-seed0-MM", lake=str(SAMPLES))
    assert by_object.dataset.url == by_path.dataset.url


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__]))


def test_a_model_that_blocks_stops_its_run_in_one_line_keeping_its_checkpoint(tmp_path, bad_plugins, monkeypatch):
    """A researcher's objective that never returns (a lock never released) hung `smtrain fit` and
    the bench's worker forever; $SMSPACE_STEP_LIMIT_S bounds a step."""
    monkeypatch.setenv("SMSPACE_STEP_LIMIT_S", "2")
    done = run_cmd("smtrain", "fit", SAMPLES / "grid-seed0-MM", "--model", "blocking", "--steps", 20,
                   "--eval-every", 10, "--out", tmp_path / "run", timeout=300)  # fmt: skip
    line = one_line(done)
    assert "took more than 2 s ($SMSPACE_STEP_LIMIT_S bounds a step)" in line, line
    assert "the checkpoint of step 0 is kept" in line, line


def test_a_model_that_blocks_on_the_probe_batch_is_refused(bad_plugins, monkeypatch):
    from smspace_bad_plugins import BlockingNet

    from smspace.train.config import TrainConfig
    from smspace.train.contract import check_model

    monkeypatch.setenv("SMSPACE_STEP_LIMIT_S", "1")
    monkeypatch.setattr(BlockingNet, "calls", 10)  # blocks on its next call
    with pytest.raises(SmspaceError, match=r"took more than 1 s on a probe batch"):
        check_model(TrainConfig(dataset="unused", model="blocking"), 2, 8)


def test_an_allocation_beyond_the_memory_limit_is_one_line(tmp_path, bad_plugins):
    """A 64 GiB allocation under `ulimit -v` gave a 105-line traceback."""
    import resource

    def limit_memory() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (16 << 30, 16 << 30))

    done = run_cmd("smtrain", "fit", SAMPLES / "grid-seed0-MM", "--model", "hungry", "--steps", 20,
                   "--eval-every", 10, "--out", tmp_path / "run", timeout=300, preexec_fn=limit_memory)  # fmt: skip
    line = one_line(done)
    assert "failed in training step" in line and "RuntimeError" in line, line
    assert "the checkpoint of step 0 is kept" in line, line


HEADLESS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage")  # as root, in a container


def _browser() -> str | None:
    """Headless Chromium (Debian's `chromium`, installed by .ci/run). Where it is absent the page
    tests skip, saying so, unless SMSPACE_REQUIRE_BROWSER is set (CI sets it): there they fail."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None and os.environ.get("SMSPACE_REQUIRE_BROWSER"):
        pytest.fail("SMSPACE_REQUIRE_BROWSER is set but no chromium is installed")
    return found


def _rendered(browser: str, page: Path, fragment: str, tmp_path: Path) -> list[tuple[str, str, str, bool]]:
    """(entry, task, mode, hidden) of the table's rows, in the order the browser shows them once the
    page's script has run on the view the fragment names."""
    from html.parser import HTMLParser

    profile = tmp_path / f"profile-{abs(hash(fragment))}"
    done = subprocess.run(
        [browser, *HEADLESS, f"--user-data-dir={profile}", "--dump-dom",
         f"{page.as_uri()}#{fragment}"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    rows: list[tuple[str, str, str, bool]] = []

    class Rows(HTMLParser):
        def handle_starttag(self, tag, attrs):
            a = dict(attrs)
            if tag == "tr" and "data-entry" in a:
                rows.append((a["data-entry"], a["data-task"], a["data-mode"], "hidden" in a))

    Rows().feed(done.stdout)
    return rows


def test_the_page_sorts_filters_and_loads_nothing_in_a_real_browser(bench, tmp_path):
    browser = _browser()
    if browser is None:
        pytest.skip("no chromium here (apt-get install chromium); CI installs it and requires it")
    done = run_cmd("smtrain", "leaderboard", bench / "out", "--out", tmp_path / "b", "--html")
    assert done.returncode == 0, done.stderr
    page = tmp_path / "b" / "leaderboard.html"
    text = page.read_text()
    assert "default-src 'none'" in text and "http://" not in text and "https://" not in text  # loads nothing
    table = json.loads((tmp_path / "b" / "leaderboard.json").read_text())["cells"]
    d_metric = {(c["entry"], c["task"], c["mode"]): c["mean"] for c in table if c["score"] == "d_metric"}
    everything = _rendered(browser, page, "", tmp_path)
    assert sorted(r[:3] for r in everything) == sorted(d_metric) and not any(r[3] for r in everything)
    ascending = _rendered(browser, page, "sort=d_metric&dir=asc", tmp_path)
    means = [d_metric[r[:3]] for r in ascending]
    assert means == sorted(means) and len(means) == len(d_metric), ascending  # the sort reorders the rows
    descending = _rendered(browser, page, "sort=d_metric&dir=desc", tmp_path)
    assert [d_metric[r[:3]] for r in descending] == sorted(means, reverse=True)
    filtered = _rendered(browser, page, "task=grid&mode=MME&sort=entry", tmp_path)
    shown = [r[:3] for r in filtered if not r[3]]
    assert shown == sorted(k for k in d_metric if k[1:] == ("grid", "MME")) and len(shown) < len(filtered)
    shot = tmp_path / "page.png"
    subprocess.run([browser, *HEADLESS, f"--user-data-dir={tmp_path / 'p'}",
                    f"--screenshot={shot}", "--window-size=1300,900", f"{page.as_uri()}#sort=d_metric"],
                   capture_output=True, timeout=120, check=True)  # fmt: skip
    assert shot.stat().st_size > 10_000  # a page was drawn, not a blank window


def test_the_published_quick_leaderboard_follows_from_its_evidence(tmp_path):
    """docs/bench/quick is what `smtrain leaderboard` makes of the results beside it: every score
    recomputed from each result's evidence (the positions from the task's own worlds) and checked,
    and the table and its JSON written again byte for byte."""
    root = Path(__file__).resolve().parents[1]
    docs = root / "docs/bench/quick"
    made = run_cmd("smtrain", "leaderboard", "docs/bench/quick/results", "--out", tmp_path / "out", cwd=root)
    assert made.returncode == 0, made.stderr
    for name in ("leaderboard.md", "leaderboard.json"):
        assert (tmp_path / "out" / name).read_bytes() == (docs / name).read_bytes(), name
    cells = json.loads((docs / "leaderboard.json").read_text())["cells"]
    assert len({cell["entry"] for cell in cells}) == 9 and {len(cell["values"]) for cell in cells} == {6}


def test_the_torus_probe_reads_the_published_results_and_agrees_with_their_probe(tmp_path):
    """benchmarks/torus_probe.py on the quick results (the grid's 10-cell torus, which the agent
    never wraps): a row per entry and mode over all 6 worlds, and its plane probe the very probe
    R² the leaderboard shows."""
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, str(root / "benchmarks/torus_probe.py"), str(root / "docs/bench/quick/results"),
         "--period", "10"], capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)["rows"]
    assert len(rows) == 27 and {r["worlds"] for r in rows} == {6}
    cells = json.loads((root / "docs/bench/quick/leaderboard.json").read_text())["cells"]
    shown = {(c["entry"], c["mode"]): c["mean"] for c in cells if c["score"] == "probe_r2"}
    assert all(abs(r["plane_mean"] - shown[(r["entry"], r["mode"])]) < 1e-12 for r in rows)
    assert all(-10 < r["torus_mean"] <= 1 for r in rows)


def test_a_results_budget_is_verified_and_ranked_against_steps(bench, tmp_path):
    """Every row carries its scores at the protocol's earlier evaluations (0 and 30 of tiny's 60),
    each with its own evidence; the leaderboard ranks the learned entries at each step and says
    whether the last step moved the ranking. A budget with a step left out, scores that do not
    follow from their evidence, or a budget on some rows only is refused, naming the file."""
    folder = bench / "out" / SHALLOW
    rows = json.loads((folder / "scores.json").read_text())["rows"]
    assert all([point["step"] for point in row["curve"]] == [0, 30] for row in rows)
    assert all((folder / "evidence" / point["h"]).is_file() for row in rows for point in row["curve"])
    isomap = json.loads((bench / "out/tiny-v1/isomap/grid/scores.json").read_text())["rows"]
    assert not any("curve" in row for row in isomap)  # it learns nothing: no budget
    made = board(bench / "out", out=tmp_path / "b")
    assert made.returncode == 0, made.stderr
    table = json.loads((tmp_path / "b/leaderboard.json").read_text())["budgets"]
    assert {c["entry"] for c in table["curves"]} == {"shallow"} and table["rankings"] == []  # one entry: no ranking
    assert (tmp_path / "b/budget.png").stat().st_size > 0
    for change, said in [
        (lambda s: [r["curve"].pop(0) for r in s["rows"]], "not the protocol's evaluations [0, 30]"),
        (lambda s: s["rows"][0]["curve"][1].update(d_metric=s["rows"][0]["curve"][1]["d_metric"] * 1.01),
         "row 0 at step 30 does not follow from its evidence"),
        (lambda s: s["rows"][1].pop("curve"), "rows have scores at earlier evaluations"),
    ]:  # fmt: skip
        copy = tmp_path / "copy"
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(bench / "out", copy)
        edit(copy / SHALLOW / "scores.json", change)
        line = one_line(board(copy, out=tmp_path / "c"))
        assert said in line and str(copy / SHALLOW) in line, line


def test_a_ranking_is_settled_only_if_the_last_step_left_it_unchanged():
    from smspace.bench.budget import markdown, rankings

    def curve(entry: str, means: list[float], score: str = "d_metric") -> dict:
        return {"task": "grid", "mode": "MM", "entry": entry, "score": score, "steps": [0, 10, 20], "means": means}

    moving = rankings([curve("a", [3, 1, 2]), curve("b", [2, 2, 1])])
    assert moving[0]["order"] == [["b", "a"], ["a", "b"], ["b", "a"]]
    assert not moving[0]["settled"] and moving[0]["last_change"] == 20
    still = rankings([curve("a", [0.1, 0.5, 0.9], "probe_r2"), curve("b", [0.2, 0.3, 0.4], "probe_r2")])
    assert still[0]["settled"] and still[0]["order"][-1] == ["a", "b"] and still[0]["last_change"] == 10
    assert "no (changed at step 20)" in "\n".join(markdown(moving))
    assert rankings([curve("a", [1, 2, 3]), {**curve("b", [1, 2]), "steps": [0, 20]}]) == []  # other budgets
