"""A result proves itself before the leaderboard shows it (docs/BENCHMARK.md, "What a result proves").

Every field of bench.json and scores.json is typed and range-checked; the suite, version, task and
protocol are those smspace fixes; the datasets are the task's (by the hash the suite pins); the
rows are exactly the task's worlds x modes at the protocol's step; the entry is in its canonical
form; the scores were written by the session and code bench.json names; and every score is derived
again here from the result's evidence (bench/evidence.py: h as saved, p from the task's setup) and
must agree to the rounding stated (TOLERANCE). Anything else is one line naming the file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from smspace.bench import evidence
from smspace.bench.names import canonical_name, canonical_params, label_of, model_defaults
from smspace.bench.representations import REPRESENTATIONS
from smspace.bench.result import BenchRecord, ScoredRow, ScoresRecord
from smspace.bench.result import shown as _shown
from smspace.bench.run import BENCH, FORMAT
from smspace.bench.run import SCORES as SCORES_FILE
from smspace.bench.scores import evaluation_steps
from smspace.bench.suite import Task, datasets_hash, get_suite
from smspace.common.differing import differing
from smspace.common.errors import DatasetCorrupt, SmspaceError
from smspace.lake.records import BENCH_RESULT, BENCH_SCORES, Record
from smspace.lake.store import Store
from smspace.metrics.scores import SCORES, scores_of

# Scores derived again agree with the stored ones to this (relative, absolute): the same numpy on
# another CPU sums in another order (LAPACK's least squares, pairwise sums), never more than ~1e-12.
TOLERANCE = (1e-9, 1e-12)


@dataclass(frozen=True)
class Result:
    where: str
    suite: str
    version: int
    task: str
    entry: str  # its label: NAME or NAME (key=value, …), canonical
    key: str  # what makes two results one entry: the label, case-folded
    code: str  # the code that made the scores: a plugin's code hash, or smspace's commit or version
    wall_s: float  # over the sessions whose time is known
    wall_complete: bool  # False: a session was killed before it could record its time
    rows: list[ScoredRow]


class NotScored(SmspaceError):
    """A result begun whose sessions have not (yet) written scores: left out with a note."""


def verify(folder: Store, where: str) -> Result:
    bench = f"{folder.url}/{BENCH}"
    record = BenchRecord.parse(_read(folder, BENCH_RESULT), bench)
    try:
        suite = get_suite(f"{record.suite}@{record.version}")
        task = suite.task(record.task["name"])
    except SmspaceError as e:
        raise SmspaceError(f"{bench}: {e}") from None
    changed = differing(record.task, task.protocol())
    if changed:
        raise SmspaceError(
            f"{bench}: task {task.name} was measured under another protocol than {suite.label} fixes "
            f"({', '.join(changed)} differ); it is not comparable"
        )
    _check_datasets(record.datasets, task, bench)
    name, params, learns = _check_entry(record.entry, bench)
    sessions = record.sessions
    if not _present(folder, SCORES_FILE):
        failed = {s.outcome for s in sessions} == {"failed"}
        said = "its sessions failed" if failed else "its first session has not ended"
        raise NotScored(f"{folder.url} is left out: {said} (no scores yet)")
    scores_file = f"{folder.url}/{SCORES_FILE}"
    raw = _read(folder, BENCH_SCORES)
    if isinstance(raw, list) or (isinstance(raw, dict) and raw.get("format", 1) == 1):  # format 1: a list of rows
        raise NotScored(
            f"{folder.url} is left out: its {SCORES_FILE} is of format 1, not {FORMAT}, and "
            "carries no evidence for its scores (measured by an older smspace); measure it again"
        )
    scores = ScoresRecord.parse(raw, scores_file)
    if learns and record.workers is None:
        raise SmspaceError(f"{bench}: a learned entry's result names the workers it was trained with")
    if scores.session >= len(sessions):
        raise SmspaceError(f"{scores_file}: session {scores.session!r} is not one of bench.json's {len(sessions)}")
    made = sessions[scores.session]
    if made.outcome != "ended":
        said = f"session {scores.session}, which it names, did not end"
        raise SmspaceError(f"{scores_file}: {said}; its scores are not its own")
    if scores.entry != record.entry:
        raise SmspaceError(f"{scores_file} was made by another entry or code than bench.json names; measure it again")
    _check_rows(scores.rows, task, learns, folder, scores_file)
    code = (record.entry.get("plugin") or {}).get("code_sha256") or made.code
    label = label_of(name, params)
    return Result(where, suite.name, suite.version, task.name, label, label.casefold(), code,
                  record.wall_s, record.wall_complete, list(scores.rows))  # fmt: skip


def _present(folder: Store, name: str) -> bool:
    try:
        folder.size(name)
    except FileNotFoundError:
        return False
    except DatasetCorrupt:
        raise SmspaceError(f"{folder.url}/{name}: not a regular file (a link, folder or special file)") from None
    return True


def _read(folder: Store, record: Record) -> Any:
    try:
        return record.load(folder)
    except FileNotFoundError:
        raise SmspaceError(f"{folder.url}/{record.file} is missing") from None
    except OSError as e:  # a link, a FIFO, a folder: never followed nor opened
        raise SmspaceError(f"{folder.url}/{record.file} cannot be read as a result's file ({e})") from None


def _check_datasets(datasets: dict[str, str], task: Task, where: str) -> None:
    ids = {task.dataset_of(w, m) for w in task.world_seeds for m in task.modes}
    if set(datasets) != ids:
        raise SmspaceError(f"{where}: datasets are not the task's {len(ids)} ({task.name}'s worlds x modes)")
    if datasets_hash(datasets) != task.datasets_hash:
        raise SmspaceError(f"{where}: its datasets' config hashes are not the ones task {task.name} fixes")


def _check_entry(entry: dict[str, Any], where: str) -> tuple[str, dict[str, Any], bool]:
    try:
        name = canonical_name(entry.get("name"))
        params = entry.get("params")
        defaults = _defaults_here(name)
        canonical = canonical_params(params, defaults, f"entry {name!r}")
    except SmspaceError as e:
        raise SmspaceError(f"{where}: {e}") from None
    if canonical != params or list(canonical) != list(params):
        raise SmspaceError(f"{where}: entry parameters {_shown(params)} are not in their canonical form ({canonical})")
    learns = name not in REPRESENTATIONS
    if entry.get("learns") is not learns:
        raise SmspaceError(f"{where}: entry {name!r} {'learns' if learns else 'learns nothing'}, not as it says")
    if learns:
        plugin = entry.get("plugin")
        if not isinstance(plugin, dict) or not all(isinstance(v, str) and len(v) <= 200 for v in plugin.values()):
            raise SmspaceError(f"{where}: entry plugin is not a record of its package and code")
        code = plugin.get("code_sha256", "")
        if plugin and not (len(code) in (16, 64) and all(c in "0123456789abcdef" for c in code)):
            raise SmspaceError(f"{where}: entry plugin code_sha256 {_shown(code)} is not a hash")
        if set(entry) != {"name", "params", "learns", "plugin"}:
            raise SmspaceError(f"{where}: entry has other fields than name, params, learns and plugin")
    elif params or set(entry) != {"name", "params", "learns"}:
        raise SmspaceError(f"{where}: entry {name!r} learns nothing and takes no parameters")
    return name, params, learns


def _defaults_here(name: str) -> dict[str, Any] | None:
    """The model's defaults where it is installed here (its parameters then checked as the bench
    checks them), None where it is not (their form is checked, not their names)."""
    if name in REPRESENTATIONS:
        return {}
    from smspace.train.config import MODELS

    try:
        return model_defaults(MODELS.get(name))
    except SmspaceError:
        return None


def _check_follows(again: dict[str, float], stored: dict[str, float], where: str) -> None:
    rel, absolute = TOLERANCE
    wrong = [s for s in SCORES if not math.isclose(again[s], stored[s], rel_tol=rel, abs_tol=absolute)]
    if wrong:
        said = ", ".join(f"{s} {stored[s]!r} (its evidence gives {again[s]!r})" for s in wrong)
        raise SmspaceError(f"{where} does not follow from its evidence: {said}")


def _check_curve(row: ScoredRow, i: int, task: Task, folder: Store, p: np.ndarray, where: str) -> None:
    """A row's budget, where it has one: exactly the protocol's evaluations before the last (a
    curve with a step left out or added would rank entries on different budgets), each score one
    it can take and derived again from its own evidence."""
    if not row.curve:
        return
    steps = [point.step for point in row.curve]
    if steps != evaluation_steps(task.steps, task.eval_every):
        raise SmspaceError(f"{where}: row {i} has scores at steps {steps}, not the protocol's evaluations "
                           f"{evaluation_steps(task.steps, task.eval_every)}")  # fmt: skip
    for point in row.curve:
        at = f"{where}: row {i} at step {point.step}"
        for score in SCORES.values():
            if not score.can_take(point.scores[score.name], task.n_h):
                said = _shown(point.scores[score.name])
                raise SmspaceError(f"{at} has {score.name} {said}, not a number it can take")
        if point.h != evidence.file_of(row.world, row.mode, point.step):
            raise SmspaceError(f"{at} names no evidence of its own (h, h_sha256)")
        h = evidence.load(folder, point.h, point.h_sha256, (len(p), task.n_h))
        try:
            again = scores_of(h, p, row.world)
        except SmspaceError as e:
            raise SmspaceError(f"{folder.url}/{evidence.EVIDENCE}/{point.h}: {e}; it is not scored") from None
        _check_follows(again, point.scores, at)


def _check_rows(rows: tuple[ScoredRow, ...], task: Task, learns: bool, folder: Store, where: str) -> None:
    expected = {(w, m) for w in task.world_seeds for m in task.modes}
    if len(rows) != len(expected):
        raise SmspaceError(f"{where}: {len(rows)} scored runs, where task {task.name} has "
                           f"{task.worlds} worlds x {len(task.modes)} modes")  # fmt: skip
    seen, step = set(), task.steps if learns else 0
    for i, row in enumerate(rows):  # first every row's world and mode: exactly the task's, each once
        if (row.world, row.mode) not in expected or (row.world, row.mode) in seen:
            raise SmspaceError(f"{where}: row {i} is world {_shown(row.world)}, mode {_shown(row.mode)}: not one of "
                               f"task {task.name}'s worlds x modes, or one counted twice")  # fmt: skip
        seen.add((row.world, row.mode))
    with_curve = sum(1 for row in rows if row.curve)
    if with_curve and not learns:
        raise SmspaceError(f"{where}: scores at earlier evaluations, for an entry that learns nothing (no budget)")
    if with_curve not in (0, len(rows)):
        raise SmspaceError(f"{where}: {with_curve} of {len(rows)} rows have scores at earlier evaluations; "
                           "a result's rows share one budget")  # fmt: skip
    for i, row in enumerate(rows):
        if row.step != step:
            raise SmspaceError(f"{where}: row {i} was scored at step {row.step}, not the protocol's {step}")
        for score in SCORES.values():
            if not score.can_take(row.scores[score.name], task.n_h):
                said = _shown(row.scores[score.name])
                raise SmspaceError(f"{where}: row {i} has {score.name} {said}, not a number it can take")
        if row.h != evidence.file_of(row.world, row.mode):
            said = f"world {row.world}, mode {row.mode}"
            raise SmspaceError(f"{where}: row {i} names no evidence (h, h_sha256) of {said}")
        p = evidence.positions(task.setup, row.world)
        h = evidence.load(folder, row.h, row.h_sha256, (len(p), task.n_h))
        try:
            again = scores_of(h, p, row.world)
        except SmspaceError as e:
            raise SmspaceError(f"{folder.url}/{evidence.EVIDENCE}/{row.h}: {e}; it is not scored") from None
        _check_follows(again, row.scores, f"{where}: row {i}")
        _check_curve(row, i, task, folder, p, where)
