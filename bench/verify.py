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

from smspace.bench import evidence
from smspace.bench.names import canonical_name, canonical_params, label_of, model_defaults
from smspace.bench.representations import REPRESENTATIONS
from smspace.bench.run import BENCH, FORMAT
from smspace.bench.run import SCORES as SCORES_FILE
from smspace.bench.suite import Task, datasets_hash, get_suite
from smspace.common.differing import differing
from smspace.common.errors import DatasetCorrupt, SmspaceError
from smspace.lake.manifest import dataset_id
from smspace.lake.records import BENCH_RESULT, BENCH_SCORES, Record
from smspace.lake.store import Store
from smspace.metrics.scores import SCORES, scores_of

# Scores derived again agree with the stored ones to this (relative, absolute): the same numpy on
# another CPU sums in another order (LAPACK's least squares, pairwise sums), never more than ~1e-12.
TOLERANCE = (1e-9, 1e-12)
MAX_WALL_S = 10 * 365 * 86400.0  # a session longer than ten years is not a measurement


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
    rows: list[dict[str, Any]]


class NotScored(SmspaceError):
    """A result begun whose sessions have not (yet) written scores: left out with a note."""


def verify(folder: Store, where: str) -> Result:
    bench = f"{folder.url}/{BENCH}"
    record = _dict(_read(folder, BENCH_RESULT), bench)
    BENCH_RESULT.format_of(record, bench)
    suite_name, version = _typed(record, "suite", str, bench), _typed(record, "version", int, bench)
    try:
        suite = get_suite(f"{suite_name}@{version}")
        task_block = _dict(record.get("task"), f"{bench}: task")
        task = suite.task(_typed(task_block, "name", str, bench))
    except SmspaceError as e:
        raise SmspaceError(f"{bench}: {e}") from None
    protocol = task.protocol()
    changed = differing(task_block, protocol)
    if changed:
        raise SmspaceError(
            f"{bench}: task {task.name} was measured under another protocol than {suite.label} fixes "
            f"({', '.join(changed)} differ); it is not comparable"
        )
    _check_datasets(record.get("datasets"), task, bench)
    entry = _dict(record.get("entry"), f"{bench}: entry")
    name, params, learns = _check_entry(entry, bench)
    sessions = _check_sessions(record.get("sessions"), bench)
    if not _present(folder, SCORES_FILE):
        outcomes = {_outcome(s) for s in sessions}
        said = "its sessions failed" if outcomes == {"failed"} else "its first session has not ended"
        raise NotScored(f"{folder.url} is left out: {said} (no scores yet)")
    scores_file = f"{folder.url}/{SCORES_FILE}"
    raw = _read(folder, BENCH_SCORES)
    scores = {"format": 1} if isinstance(raw, list) else _dict(raw, scores_file)  # format 1: a list of rows
    if scores.get("format", 1) == 1:
        raise NotScored(
            f"{folder.url} is left out: its {SCORES_FILE} is of format 1, not {FORMAT}, and "
            "carries no evidence for its scores (measured by an older smspace); measure it again"
        )
    BENCH_SCORES.format_of(scores, scores_file)
    if learns and not (isinstance(record.get("workers"), int) and not isinstance(record["workers"], bool)):
        raise SmspaceError(f"{bench}: a learned entry's result names the workers it was trained with")
    session = scores.get("session")
    if not isinstance(session, int) or isinstance(session, bool) or not 0 <= session < len(sessions):
        raise SmspaceError(f"{scores_file}: session {session!r} is not one of bench.json's {len(sessions)}")
    if _outcome(sessions[session]) != "ended":
        raise SmspaceError(f"{scores_file}: session {session}, which it names, did not end; its scores are not its own")
    if scores.get("entry") != entry:
        raise SmspaceError(f"{scores_file} was made by another entry or code than bench.json names; measure it again")
    rows = _check_rows(scores.get("rows"), task, learns, folder, scores_file)
    plugin = entry.get("plugin") or {}
    made = sessions[session]
    code = plugin.get("code_sha256") or str(made.get("git_commit") or made.get("smspace") or "?")
    walls = [s["wall_s"] for s in sessions]
    label = label_of(name, params)
    return Result(where, suite.name, suite.version, task.name, label, label.casefold(), code,
                  sum(w for w in walls if w is not None), None not in walls, rows)  # fmt: skip


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


def _dict(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise SmspaceError(f"{where} is a {type(value).__name__}, not a table of fields")
    return value


def _typed(block: dict[str, Any], key: str, kind: type, where: str) -> Any:
    value = block.get(key)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise SmspaceError(f"{where}: {key} is {_shown(value)}, not a {kind.__name__}")
    return value


def _check_datasets(datasets: Any, task: Task, where: str) -> None:
    ids = {dataset_id(task.setup, w, m) for w in task.world_seeds for m in task.modes}
    if not isinstance(datasets, dict) or set(datasets) != ids or not all(isinstance(v, str) for v in datasets.values()):
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


def _check_sessions(sessions: Any, where: str) -> list[dict[str, Any]]:
    if not isinstance(sessions, list) or not sessions or len(sessions) > 10_000:
        raise SmspaceError(f"{where}: sessions is {_shown(sessions)}, not a list of the sessions that made it")
    for i, session in enumerate(sessions):
        if not isinstance(session, dict):
            raise SmspaceError(f"{where}: session {i} is not a table of fields")
        wall = session.get("wall_s")
        if wall is not None and not _finite(wall, 0.0, MAX_WALL_S):
            raise SmspaceError(f"{where}: session {i} has wall_s {_shown(wall)}, not seconds (finite, >= 0)")
        outcome = _outcome(session)
        if outcome not in (None, "ended", "failed") or (wall is None) != (outcome is None):
            raise SmspaceError(f"{where}: session {i} has outcome {_shown(outcome)} with wall_s {_shown(wall)}")
    return sessions


def _check_rows(rows: Any, task: Task, learns: bool, folder: Store, where: str) -> list[dict[str, Any]]:
    expected = {(w, m) for w in task.world_seeds for m in task.modes}
    if not isinstance(rows, list) or len(rows) != len(expected):
        count = len(rows) if isinstance(rows, list) else _shown(rows)
        raise SmspaceError(f"{where}: {count} scored runs, where task {task.name} has "
                           f"{task.worlds} worlds x {len(task.modes)} modes")  # fmt: skip
    seen, step = set(), task.steps if learns else 0
    for i, row in enumerate(rows):  # first every row's world and mode: exactly the task's, each once
        row = _dict(row, f"{where}: row {i}")
        world, mode = row.get("world"), row.get("mode")
        hashable = isinstance(world, int | str) and isinstance(mode, int | str)
        if not hashable or (world, mode) not in expected or isinstance(world, bool) or (world, mode) in seen:
            raise SmspaceError(f"{where}: row {i} is world {_shown(world)}, mode {_shown(mode)}: not one of task "
                               f"{task.name}'s worlds x modes, or one counted twice")  # fmt: skip
        seen.add((world, mode))
    for i, row in enumerate(rows):
        world, mode = row["world"], row["mode"]
        if row.get("step") != step or isinstance(row.get("step"), bool):
            said = _shown(row.get("step"))
            raise SmspaceError(f"{where}: row {i} was scored at step {said}, not the protocol's {step}")
        if not _finite(row.get("wall_s"), 0.0, MAX_WALL_S):
            raise SmspaceError(f"{where}: row {i} has wall_s {_shown(row.get('wall_s'))}, not seconds (finite, >= 0)")
        for score in SCORES.values():
            if not score.can_take(row.get(score.name), task.n_h):
                said = _shown(row.get(score.name))
                raise SmspaceError(f"{where}: row {i} has {score.name} {said}, not a number it can take")
        name, digest = row.get("h"), row.get("h_sha256")
        if name != evidence.file_of(world, mode) or not isinstance(digest, str):
            raise SmspaceError(f"{where}: row {i} names no evidence (h, h_sha256) of world {world}, mode {mode}")
        p = evidence.positions(task.setup, world)
        h = evidence.load(folder, name, digest, (len(p), task.n_h))
        try:
            again = scores_of(h, p, world)
        except SmspaceError as e:
            raise SmspaceError(f"{folder.url}/{evidence.EVIDENCE}/{name}: {e}; it is not scored") from None
        rel, absolute = TOLERANCE
        wrong = [s for s in SCORES if not math.isclose(again[s], row[s], rel_tol=rel, abs_tol=absolute)]
        if wrong:
            shown = ", ".join(f"{s} {row[s]!r} (its evidence gives {again[s]!r})" for s in wrong)
            raise SmspaceError(f"{where}: row {i} does not follow from its evidence: {shown}")
    return rows


def _outcome(session: dict[str, Any]) -> str | None:
    """How a session ended: "ended", "failed", None (killed); sessions recorded before outcomes
    were ended when their wall time is known."""
    return session.get("outcome", None if session.get("wall_s") is None else "ended")


def _finite(value: Any, low: float, high: float) -> bool:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    return number and math.isfinite(value) and low <= value <= high


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
