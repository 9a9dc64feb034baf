"""`smtrain bench SUITE ENTRY…`: each entry on each task of a suite, and its scores.

Layout: OUT/<suite>-v<version>/<entry>/<task>/ holds a study (study/runner.py: resumable, on any
executor, its runs ordinary run folders), `bench.json` (the suite, version, task and protocol, the
entry and its code, the datasets' config hashes, and each session's wall time) and `scores.json`
(one row per run: world, mode, the scores of bench/scores.py). An entry that learns nothing
(bench/representations.py) has no runs: its rows are computed from the datasets.
"""

from __future__ import annotations

import datetime
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smspace.bench import evidence
from smspace.bench.names import canonical_name, canonical_params, folder_of, label_of, model_defaults
from smspace.bench.representations import REPRESENTATIONS
from smspace.bench.result import BenchRecord, CurvePoint, ScoredRow, ScoresRecord, Session
from smspace.bench.scores import run_curve, run_scores
from smspace.bench.suite import Suite, Task, datasets_hash
from smspace.common.cli import default_workers
from smspace.common.differing import differing
from smspace.common.errors import SmspaceError
from smspace.common.processes import alive
from smspace.common.progress import duration
from smspace.common.provenance import cpu, git_commit, version
from smspace.lake.dataset import Dataset
from smspace.lake.records import BENCH_RESULT, BENCH_SCORES, UnknownFormat
from smspace.lake.store import Store, exists, listing, open_store, within
from smspace.metrics.scores import scores_of

BENCH = BENCH_RESULT.file
SCORES = BENCH_SCORES.file
LOCK = "bench.lock"  # held by the bench writing the result: a second one into the same folder is refused
FORMAT = BENCH_SCORES.writes  # of scores.json: 2 carries evidence (bench/evidence.py); 1 did not, and is not shown


@dataclass(frozen=True)
class Entry:
    """A model (smspace's, or any package's registered one) with its parameters, or a
    representation that learns nothing."""

    name: str
    params: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, name: Any, params: Any = None) -> Entry:
        """The entry in its canonical form (bench/names.py), refused in one line if it has none: an
        unknown model, a parameter the model does not take, a value it cannot hold."""
        name = canonical_name(name)
        if name in REPRESENTATIONS:
            if params:
                raise SmspaceError(f"entry {name!r} learns nothing and takes no parameters")
            return cls(name, {})
        from smspace.train.config import MODELS

        defaults = model_defaults(MODELS.get(name))
        return cls(name, canonical_params(params or {}, defaults, f"entry {name!r}"))

    @property
    def learns(self) -> bool:
        return self.name not in REPRESENTATIONS

    @property
    def folder(self) -> str:
        return folder_of(self.name, self.params)

    @property
    def label(self) -> str:
        return label_of(self.name, self.params)

    def record(self) -> dict[str, Any]:
        """What the entry is: a registered model's package and code hash included."""
        record: dict[str, Any] = {"name": self.name, "params": self.params, "learns": self.learns}
        if self.learns:
            from smspace.train.model import plugin_record

            record["plugin"] = plugin_record(self.name)
        return record

    def check(self) -> None:
        """Refused before anything is generated or written: an entry not in its canonical form."""
        if Entry.of(self.name, self.params) != self:
            raise SmspaceError(
                f"entry {self.label!r} is not in its canonical form ({Entry.of(self.name, self.params).label!r})"
            )


def check_task(suite: Suite, task: Task) -> dict[str, str]:
    """The task's datasets as this smspace configures them, refused if they are not the ones the
    suite version fixed (generation changed: its results would not be comparable)."""
    datasets = task.datasets()
    if datasets_hash(datasets) != task.datasets_hash:
        raise SmspaceError(
            f"suite {suite.label}, task {task.name}: this smspace configures its datasets differently "
            f"(hash {datasets_hash(datasets)}, the suite fixed {task.datasets_hash}); its results would not compare"
        )
    return datasets


def run_bench(
    suite: Suite,
    entries: list[Entry],
    lake: Store | str,
    out: Store | str,
    workers: int = 1,
    gen_workers: int = 1,
    executor: str = "local",
    overwrite: bool = False,
    notify: Callable[[str], None] = lambda line: None,
) -> list[Store]:
    """Every entry on every task (each resumed where it stopped); returns the task folders. Every
    refusal (an entry, a task, the folders, an earlier result, a model's contract) comes before
    anything is generated or written."""
    lake, out = _refusals(suite, entries, lake, out, workers, overwrite)
    remove_stale_temporaries()
    done = []
    for task in suite.tasks:  # task by task: a leaderboard fills a column at a time
        _generate(task, lake, gen_workers, executor, notify)  # before any entry: no entry's time includes it
        _check_lake(lake, suite, task)
        for entry in entries:
            folder = _folder(out, suite, task, entry)
            notify(f"bench: {suite.label} {entry.folder} on {task.name}")
            folder.make()
            with folder.lock(LOCK, f"another smtrain bench is writing {folder.url}", wait=False):
                session = _begin(folder, suite, task, entry, workers, executor, overwrite)
                clock = time.monotonic()
                try:
                    if entry.learns:
                        rows = _train(task, entry, lake, folder, workers, gen_workers, executor, overwrite, notify)
                    else:
                        rows = _represent(task, entry, lake, folder)
                except BaseException:
                    _end(folder, session, time.monotonic() - clock, "failed")
                    raise
                ScoresRecord(entry.record(), session, tuple(rows)).write(folder)
                _end(folder, session, time.monotonic() - clock, "ended")
            done.append(folder)
    return done


def _refusals(
    suite: Suite, entries: list[Entry], lake: Store | str, out: Store | str, workers: int, overwrite: bool
) -> tuple[Store, Store]:
    """Every refusal a bench (or its dry run) makes before anything is generated or written: an
    entry not in its canonical form, a task whose datasets this smspace configures otherwise, the
    folders, an earlier result made on other terms, a lake of another suite's sizes, a model's
    contract. Returns the lake and out opened."""
    for entry in entries:
        entry.check()
    for task in suite.tasks:
        check_task(suite, task)
    lake, out = open_store(lake), open_store(out)
    check_folders(lake, out)
    _check_earlier(suite, entries, out, overwrite, workers)
    for task in suite.tasks:
        _check_lake(lake, suite, task, missing_ok=True)
        for entry in entries:
            if entry.learns:
                check_entry_model(task, entry)
    return lake, out


def check_folders(lake: Store, out: Store) -> None:
    """--out is a folder apart from the lake (results inside the datasets they were measured on,
    or datasets inside results, would be deleted or listed as the other)."""
    for store, flag in ((out, "--out"), (lake, "--lake")):
        if store.is_file():
            raise SmspaceError(f"{flag} {store.url} is a file, not a folder")
    if within(out, lake) or within(lake, out):
        raise SmspaceError(f"--out {out.url} and --lake {lake.url} must be apart (neither inside the other)")


def check_entry_model(task: Task, entry: Entry) -> None:
    """The entry's model on the task's setup, held to its contract (a probe batch, alone and
    stacked: train/contract.py) before any dataset or result is written."""
    from smspace.datagen.setups import get_setup
    from smspace.study.sweep import check_study_model
    from smspace.train.config import TrainConfig

    template = TrainConfig(dataset="", model=entry.name, model_params=dict(entry.params), n_h=task.n_h,
                           steps=task.steps, eval_every=task.eval_every)  # fmt: skip
    encoder, walk = get_setup(task.setup).encoder_layers, task.explored.record()
    check_study_model(template.for_setup(task.setup, task.transitions, encoder, walk), task.setup, task.seed)


TEMPORARY = "smspace-bench-"


def remove_stale_temporaries() -> None:
    """The study files of benches killed (kill -9) before they could remove them: a temporary
    folder names the process that made it, and is removed once that process is gone."""
    for path in Path(tempfile.gettempdir()).glob(f"{TEMPORARY}*-*"):
        pid = path.name[len(TEMPORARY) :].split("-", 1)[0]
        if pid.isdigit() and not alive(int(pid)):
            shutil.rmtree(path, ignore_errors=True)


def plan_bench(
    suite: Suite, entries: list[Entry], lake: Store | str, out: Store | str, workers: int = 1, overwrite: bool = False,
    gen_workers: int | None = None,
) -> list[str]:  # fmt: skip
    """What `run_bench` would generate, train and take, as each task's study budgets it (measured
    here and now, study/budget.py), and the whole bench's time, generation included. Writes nothing."""
    from smspace.study.runner import plan_generation, plan_study

    lake, out = _refusals(suite, entries, lake, out, workers, overwrite)
    lines, total_s = [], 0.0
    lines += busy_cores_note()
    for task in suite.tasks:
        generate_s, _, line = plan_generation(task.setup, task.world_seeds, task.modes, task.transitions, lake,
                                              gen_workers or workers, exploration=task.explored)  # fmt: skip
        lines.append(f"{suite.label} task {task.name}: {line}")
        total_s += generate_s  # once per task, whichever entry comes first
        for entry in entries:
            folder = _folder(out, suite, task, entry)
            lines.append(f"{suite.label} {entry.folder} on {task.name}:")
            if not entry.learns:
                lines.append(f"  learns nothing: {task.worlds * len(task.modes)} representations of the regular states")
                continue
            request = task_request(task, entry)
            plan = plan_study(request, lake, folder, workers, overwrite)
            lines += [f"  {line}" for line in plan.lines[1:-1] if not line.startswith("datasets of ")]
            total_s += plan.train_s
    lines.append(
        f"bench: about {duration(total_s)} on {workers} worker(s), generation included, at the rates measured now"
    )
    lines.append("dry run: nothing was written")
    return lines


BUSY_LOAD = 0.5  # of the cores: above it the rates measured now are those of a shared machine


def busy_cores_note() -> list[str]:
    """A dry run measures its rates now: on cores busy with other work they are slower than an idle
    machine's, and a bench that runs beside that work takes longer than an idle machine would."""
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    if load <= BUSY_LOAD * cores:
        return []
    return [
        f"note: the cores are busy (load {load:.1f} on {cores} cores): the rates below are measured beside that "
        "work, so the estimate holds only while it goes on; on an idle machine a bench runs faster, beside more "
        "work slower (times measured 1.3-3x off on a shared machine)"
    ]


def _folder(out: Store, suite: Suite, task: Task, entry: Entry) -> Store:
    return out.child(suite.label).child(entry.folder).child(task.name)


def _check_lake(lake: Store, suite: Suite, task: Task, missing_ok: bool = False) -> None:
    """What was trained on is what the suite fixed: each dataset's recorded config hash."""
    for name, expected in task.datasets().items():
        if missing_ok and not exists(lake.child(name), "manifest.json"):
            continue
        found = Dataset.open(name, lake).manifest.config_hash
        if found != expected:
            raise SmspaceError(
                f"{lake.url}/{name} was generated with config {found}, not the {expected} that suite "
                f"{suite.label} fixes for task {task.name}; give the suite a lake of its own (--lake)"
            )


def _train(
    task: Task, entry: Entry, lake: Store, folder: Store, workers: int, gen_workers: int, executor: str,
    overwrite: bool, notify: Callable[[str], None],
) -> list[ScoredRow]:  # fmt: skip
    from smspace.study.runner import run_study

    runs = run_study(task_request(task, entry), lake, folder, overwrite, workers, gen_workers, executor, notify)
    rows = []
    for run in runs:
        row, h = run_scores(run.view, task.steps, lake)
        curve = run_curve(run.view, task.steps, task.eval_every)
        rows.append(_scored(folder, task, row, h, lake, curve))
    return rows


def _scored(
    folder: Store, task: Task, row: dict[str, Any], h: np.ndarray, lake: Store,
    curve: list[tuple[int, np.ndarray]] = (),
) -> ScoredRow:  # fmt: skip
    """The row with its evidence (h, written beside the result) and the scores derived from it and
    from the positions the task's setup gives, exactly as the leaderboard derives them again."""
    world, mode = row["world"], row["mode"]
    p = evidence.positions(task.setup, world)
    _, stored = Dataset.open(task.dataset_of(world, mode), lake).regular_sampling()
    if not np.array_equal(np.asarray(stored, np.float64), p):
        where = f"{lake.url}/{task.dataset_of(world, mode)}"
        raise SmspaceError(
            f"{where}: its regular sampling is not the one setup {task.setup} gives world {world} today; "
            "give the suite a lake of its own"
        )
    h = np.asarray(h, np.float64)
    name, digest = evidence.save(folder, world, mode, h)
    points = []
    for step, earlier in curve:  # the budget: every evaluation before the last, with its evidence
        earlier = np.asarray(earlier, np.float64)
        point_name, point_digest = evidence.save(folder, world, mode, earlier, step)
        points.append(CurvePoint(step, scores_of(earlier, p, world), point_name, point_digest))
    scores = scores_of(h, p, world)
    return ScoredRow(world, mode, row["step"], row["wall_s"], row["run"], scores, name, digest, tuple(points))


def _generate(task: Task, lake: Store, gen_workers: int, executor: str, notify: Callable[[str], None]) -> None:
    """The task's datasets, generated (or completed) if missing."""
    from smspace.datagen.generate import generate

    clock = time.monotonic()
    results = generate(
        lake, task.setup, task.modes, task.world_seeds, task.transitions, task.shard_size, workers=gen_workers,
        executor=executor, notify=notify, exploration=task.explored,
    )  # fmt: skip
    if any(new for _, new in results):
        notify(f"bench: {task.name}'s datasets generated in {time.monotonic() - clock:.0f} s")


def _represent(task: Task, entry: Entry, lake: Store, folder: Store) -> list[ScoredRow]:
    rows = []
    for seed in task.world_seeds:
        for mode in task.modes:
            ds = Dataset.open(task.dataset_of(seed, mode), lake)
            clock = time.monotonic()
            h = REPRESENTATIONS[entry.name](ds, task.n_h, seed)
            row = {"world": seed, "mode": mode, "step": 0, "wall_s": time.monotonic() - clock,
                   "run": ds.manifest.dataset_id}  # fmt: skip
            rows.append(_scored(folder, task, row, h, lake))
    return rows


def task_request(task: Task, entry: Entry):
    """The study request a learned entry trains on a task (its source, recorded beside the runs: the sections' TOML)."""
    from smspace.study.file import StudyRequest

    return StudyRequest.from_sections(study_sections(task, entry), f"task {task.name}", default_name=task.name)


def study_sections(task: Task, entry: Entry) -> dict[str, dict[str, Any]]:
    """The study a learned entry trains on a task: the task's datasets, its protocol, the entry's model."""
    study = {"name": task.name, "setup": task.setup, "modes": list(task.modes), "worlds": task.worlds,
             "seed": task.seed, "transitions": task.transitions}  # fmt: skip
    walk = task.explored
    if walk.walks:  # the study generates the task's walks, as smgen would
        study |= {"exploration": "walk", "walk_length": walk.length, "walk_step": walk.step}
    train = {"model": entry.name, "steps": task.steps, "eval_every": task.eval_every, "n_h": task.n_h}
    return {"study": study, "train": train | ({"model_params": entry.params} if entry.params else {})}


def _check_earlier(suite: Suite, entries: list[Entry], out: Store, overwrite: bool, workers: int) -> None:
    """Every earlier result checked before anything is generated or trained."""
    for task in suite.tasks:
        for entry in entries:
            _earlier(_folder(out, suite, task, entry), _record(suite, task, entry, workers), overwrite)


def _record(suite: Suite, task: Task, entry: Entry, workers: int) -> BenchRecord:
    """What a result is made on, before any session. The workers of a learned entry are a term:
    they decide which runs train stacked together, and stacked runs agree with lone ones only to
    float32 rounding (docs/BENCHMARK.md), so another count gives other bytes."""
    return BenchRecord(suite.name, suite.version, task.protocol(), entry.record(), task.datasets(),
                       workers if entry.learns else None)  # fmt: skip


def _earlier(folder: Store, made: BenchRecord, overwrite: bool) -> BenchRecord | None:
    """The result already in `folder` (None: none, or --overwrite), refused if it was made on other
    terms (another code of the entry, another protocol): its sessions would not describe this
    result. A result of another entry is never replaced, --overwrite or not."""
    if not exists(folder, BENCH):
        return None
    try:
        before = BenchRecord.read(folder)
    except UnknownFormat:  # another smspace's result: refused as it is, never replaced
        raise
    except SmspaceError as e:  # not a result of any entry
        if overwrite:
            return None
        raise SmspaceError(f"{e}; --overwrite replaces it") from None
    was, now = before.entry, made.entry
    if (was.get("name"), was.get("params")) != (now["name"], now["params"]):
        params = was.get("params") if isinstance(was.get("params"), dict) else {}
        raise SmspaceError(
            f"{folder.url} holds a result of another entry ({label_of(str(was.get('name')), params)}, not "
            f"{label_of(now['name'], now['params'])}); give another --out (--overwrite never replaces another "
            "entry's result)"
        )
    if overwrite:
        return None
    changed = differing(before.terms(), made.terms())
    if changed == ["entry"] or ("entry" in changed and was.get("plugin") != now.get("plugin")):
        code_was = (was.get("plugin") or {}).get("code_sha256", "?") if isinstance(was.get("plugin"), dict) else "?"
        code_now = (now.get("plugin") or {}).get("code_sha256", "smspace's own")
        raise SmspaceError(
            f"{folder.url} holds a result of {label_of(now['name'], now['params'])} made with other code "
            f"(code {code_was}, now {code_now}); --overwrite replaces it, or give another --out"
        )
    if changed:
        raise SmspaceError(
            f"{folder.url} holds a result made with another {', '.join(changed)}; "
            "--overwrite replaces it, or give another --out"
        )
    return before


def _begin(folder: Store, suite: Suite, task: Task, entry: Entry, workers: int, executor: str, overwrite: bool) -> int:
    """bench.json with this session in it, its wall time unknown until it ends (a session killed
    stays so: the leaderboard says the time is incomplete). A result made on other terms
    (--overwrite) loses its scores and evidence here, before any work: scores are only ever those
    of the code bench.json names. Returns the session's index."""
    made = _record(suite, task, entry, workers)
    before = _earlier(folder, made, overwrite)
    if before is None:
        _forget_scores(folder)
    made_on = {"started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "workers": workers,
               "executor": executor, "smspace": version("smspace"), "git_commit": git_commit(),
               "host": socket.gethostname(), "cores": default_workers(), **cpu()}  # fmt: skip
    record = (before or made).with_session(Session(None, None, made_on))
    folder.make()
    record.write(folder)
    return len(record.sessions) - 1


def _forget_scores(folder: Store) -> None:
    folder.delete(SCORES)
    proof = folder.child(evidence.EVIDENCE)
    for name in listing(proof, "*"):
        proof.delete(name)


def _end(folder: Store, session: int, wall_s: float, outcome: str) -> None:
    """The session's wall time and how it ended ("ended", "failed": its time counts either way)."""
    BenchRecord.read(folder).with_ended(session, wall_s, outcome).write(folder)
