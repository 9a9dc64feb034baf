"""The two records a bench result writes, as typed values: bench.json (what the result was made on
and the sessions that made it) and scores.json (its rows, by the session that wrote them).

Each is parsed here field by field, types and bounds, one line naming the file otherwise; so
bench/verify.py checks what the fields mean (the suite's protocol, the task's worlds, the evidence)
on typed values, and bench/run.py writes both from these classes, never from a dict built by hand.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from smspace.common.errors import SmspaceError
from smspace.lake.records import BENCH_RESULT, BENCH_SCORES
from smspace.lake.store import Store
from smspace.metrics.scores import SCORES

MAX_WALL_S = 10 * 365 * 86400.0  # a session longer than ten years is not a measurement
MAX_SESSIONS = 10_000
MAX_DATASETS = 100_000
MAX_CURVE = 1000  # evaluations before the last that a row may carry scores of
OUTCOMES = ("ended", "failed")  # a session killed before it could say has none


@dataclass(frozen=True)
class Session:
    """One `smtrain bench` session on the result: how long it took and how it ended (None, None:
    killed before it could record either), and what it ran on (`made_on`, as recorded: when, the
    workers and executor, smspace's version and commit, the host and its CPU)."""

    wall_s: float | None
    outcome: str | None
    made_on: dict[str, Any]

    @property
    def code(self) -> str:
        """The code the session ran: smspace's commit, or its version where it had none."""
        return str(self.made_on.get("git_commit") or self.made_on.get("smspace") or "?")

    def ended(self, wall_s: float, outcome: str) -> Session:
        return replace(self, wall_s=wall_s, outcome=outcome)

    def to_json(self) -> dict[str, Any]:
        return self.made_on | {"wall_s": self.wall_s, "outcome": self.outcome}

    @classmethod
    def parse(cls, raw: Any, where: str, index: int) -> Session:
        if not isinstance(raw, dict):
            raise SmspaceError(f"{where}: session {index} is not a table of fields")
        wall = raw.get("wall_s")
        if wall is not None and not finite(wall, 0.0, MAX_WALL_S):
            raise SmspaceError(f"{where}: session {index} has wall_s {shown(wall)}, not seconds (finite, >= 0)")
        # sessions recorded before outcomes were: ended where their wall time is known
        outcome = raw.get("outcome", None if wall is None else "ended")
        if outcome not in (None, *OUTCOMES) or (wall is None) != (outcome is None):
            raise SmspaceError(f"{where}: session {index} has outcome {shown(outcome)} with wall_s {shown(wall)}")
        made_on = {k: v for k, v in raw.items() if k not in ("wall_s", "outcome")}
        return cls(float(wall) if wall is not None else None, outcome, made_on)


@dataclass(frozen=True)
class BenchRecord:
    """bench.json: the suite, version and task protocol a result was measured under, the entry and
    its code, the datasets' config hashes, a learned entry's workers, and every session so far."""

    suite: str
    version: int
    task: dict[str, Any]  # the protocol (bench/suite.py, Task.protocol): checked against it by verify
    entry: dict[str, Any]  # bench/run.py, Entry.record(): checked for its canonical form by verify
    datasets: dict[str, str]  # dataset id -> config hash
    workers: int | None  # a learned entry's: which runs train stacked together decides the bytes
    sessions: tuple[Session, ...] = ()

    def terms(self) -> dict[str, Any]:
        """What the result was made on: a result is resumed only on the same terms."""
        terms = {"suite": self.suite, "version": self.version, "task": self.task, "entry": self.entry,
                 "datasets": self.datasets}  # fmt: skip
        return terms | ({"workers": self.workers} if self.workers is not None else {})

    def with_session(self, session: Session) -> BenchRecord:
        return replace(self, sessions=(*self.sessions, session))

    def with_ended(self, index: int, wall_s: float, outcome: str) -> BenchRecord:
        sessions = list(self.sessions)
        sessions[index] = sessions[index].ended(wall_s, outcome)
        return replace(self, sessions=tuple(sessions))

    @property
    def wall_s(self) -> float:
        """Over the sessions whose time is known."""
        return sum(s.wall_s for s in self.sessions if s.wall_s is not None)

    @property
    def wall_complete(self) -> bool:
        """False: a session was killed before it could record its time."""
        return all(s.wall_s is not None for s in self.sessions)

    def write(self, folder: Store) -> None:
        BENCH_RESULT.write(folder, self.terms() | {"sessions": [s.to_json() for s in self.sessions]})

    @classmethod
    def read(cls, folder: Store) -> BenchRecord:
        """The record in `folder` (FileNotFoundError if absent; SmspaceError naming it if malformed)."""
        where = f"{folder.url}/{BENCH_RESULT.file}"
        return cls.parse(BENCH_RESULT.load(folder), where)

    @classmethod
    def parse(cls, raw: Any, where: str) -> BenchRecord:
        raw = table(raw, where)
        BENCH_RESULT.format_of(raw, where)
        suite, version = typed(raw, "suite", str, where), typed(raw, "version", int, where)
        task = table(raw.get("task"), f"{where}: task")
        typed(task, "name", str, where)
        datasets = raw.get("datasets")
        if not isinstance(datasets, dict) or len(datasets) > MAX_DATASETS:
            raise SmspaceError(f"{where}: datasets is {shown(datasets)}, not a table of dataset ids and hashes")
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in datasets.items()):
            raise SmspaceError(f"{where}: datasets are not dataset ids with their config hashes")
        entry = table(raw.get("entry"), f"{where}: entry")
        workers = raw.get("workers")
        if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
            raise SmspaceError(f"{where}: workers is {shown(workers)}, not a count of workers")
        sessions = raw.get("sessions")
        if not isinstance(sessions, list) or not sessions or len(sessions) > MAX_SESSIONS:
            raise SmspaceError(f"{where}: sessions is {shown(sessions)}, not a list of the sessions that made it")
        parsed = tuple(Session.parse(s, where, i) for i, s in enumerate(sessions))
        return cls(suite, version, task, entry, datasets, workers, parsed)


@dataclass(frozen=True)
class CurvePoint:
    """A row's scores at an evaluation before its last, with the evidence they follow from: what
    the task's budget is judged on (docs/BENCHMARK.md, "Budgets")."""

    step: int
    scores: dict[str, float]
    h: str
    h_sha256: str

    def to_json(self) -> dict[str, Any]:
        return {"step": self.step, "h": self.h, "h_sha256": self.h_sha256, **self.scores}

    @classmethod
    def parse(cls, raw: Any, where: str) -> CurvePoint:
        point = table(raw, where)
        step, h, digest = point.get("step"), point.get("h"), point.get("h_sha256")
        if not isinstance(step, int) or isinstance(step, bool) or step < 0:
            raise SmspaceError(f"{where} is at step {shown(step)}, not a step")
        for name in SCORES:
            if not finite(point.get(name), -math.inf, math.inf):
                raise SmspaceError(f"{where} has {name} {shown(point.get(name))}, not a number it can take")
        if not isinstance(h, str) or not isinstance(digest, str):
            raise SmspaceError(f"{where} names no evidence (h, h_sha256)")
        return cls(step, {name: float(point[name]) for name in SCORES}, h, digest)


@dataclass(frozen=True)
class ScoredRow:
    """One world and mode of a result: the step and wall time it was scored at, its scores (those
    of metrics/scores.py) and the evidence they follow from (bench/evidence.py: h's file and sha256)."""

    world: int
    mode: str
    step: int
    wall_s: float
    run: str  # the run (or, for an entry that learns nothing, the dataset) it was scored on
    scores: dict[str, float]
    h: str
    h_sha256: str
    curve: tuple[CurvePoint, ...] = ()  # the evaluations before `step`, in order (none: not recorded)

    def to_json(self) -> dict[str, Any]:
        curve = {"curve": [point.to_json() for point in self.curve]} if self.curve else {}
        return {"world": self.world, "mode": self.mode, "step": self.step, "wall_s": self.wall_s, "run": self.run,
                "h": self.h, "h_sha256": self.h_sha256, **self.scores, **curve}  # fmt: skip

    @classmethod
    def parse(cls, raw: Any, where: str, index: int) -> ScoredRow:
        row = table(raw, f"{where}: row {index}")
        world, mode = row.get("world"), row.get("mode")
        if not isinstance(world, int) or isinstance(world, bool) or not isinstance(mode, str):
            raise SmspaceError(f"{where}: row {index} is world {shown(world)}, mode {shown(mode)}: not a world "
                               "seed and a mode")  # fmt: skip
        step = row.get("step")
        if not isinstance(step, int) or isinstance(step, bool) or step < 0:
            raise SmspaceError(f"{where}: row {index} was scored at step {shown(step)}, not a step")
        wall = row.get("wall_s")
        if not finite(wall, 0.0, MAX_WALL_S):
            raise SmspaceError(f"{where}: row {index} has wall_s {shown(wall)}, not seconds (finite, >= 0)")
        for name in SCORES:
            if not finite(row.get(name), -math.inf, math.inf):
                raise SmspaceError(f"{where}: row {index} has {name} {shown(row.get(name))}, not a number it can take")
        h, digest = row.get("h"), row.get("h_sha256")
        if not isinstance(h, str) or not isinstance(digest, str):
            raise SmspaceError(f"{where}: row {index} names no evidence (h, h_sha256) of world {world}, mode {mode}")
        run = row.get("run", "")
        scores = {name: float(row[name]) for name in SCORES}
        curve = row.get("curve", [])
        if not isinstance(curve, list) or len(curve) > MAX_CURVE:
            raise SmspaceError(f"{where}: row {index} has a curve of {shown(curve)}, not a list of evaluations")
        points = tuple(CurvePoint.parse(c, f"{where}: row {index}, evaluation {j}") for j, c in enumerate(curve))
        return cls(world, mode, step, float(wall), run if isinstance(run, str) else "", scores, h, digest, points)


@dataclass(frozen=True)
class ScoresRecord:
    """scores.json: the rows, written by one session of bench.json for the entry and code it names."""

    entry: dict[str, Any]
    session: int
    rows: tuple[ScoredRow, ...]

    def write(self, folder: Store) -> None:
        BENCH_SCORES.write(folder, {"entry": self.entry, "session": self.session,
                                    "rows": [r.to_json() for r in self.rows]})  # fmt: skip

    @classmethod
    def parse(cls, raw: Any, where: str) -> ScoresRecord:
        raw = table(raw, where)
        BENCH_SCORES.format_of(raw, where)
        session = raw.get("session")
        if not isinstance(session, int) or isinstance(session, bool) or session < 0:
            raise SmspaceError(f"{where}: session {session!r} is not a session of bench.json")
        rows = raw.get("rows")
        if not isinstance(rows, list):
            raise SmspaceError(f"{where}: {shown(rows)} scored runs, not a list of rows")
        return cls(table(raw.get("entry"), f"{where}: entry"), session,
                   tuple(ScoredRow.parse(r, where, i) for i, r in enumerate(rows)))  # fmt: skip


def table(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise SmspaceError(f"{where} is a {type(value).__name__}, not a table of fields")
    return value


def typed(block: dict[str, Any], key: str, kind: type, where: str) -> Any:
    value = block.get(key)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise SmspaceError(f"{where}: {key} is {shown(value)}, not a {kind.__name__}")
    return value


def finite(value: Any, low: float, high: float) -> bool:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    return number and math.isfinite(value) and low <= value <= high


def shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
