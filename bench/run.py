"""`smtrain bench SUITE ENTRY…`: each entry on each task of a suite, and its scores.

Layout: OUT/<suite>-v<version>/<entry>/<task>/ holds a study (study/runner.py: resumable, on any
executor, its runs ordinary run folders), `bench.json` (the suite, version, task and protocol, the
entry and its code, the datasets' config hashes, and each session's wall time) and `scores.json`
(one row per run: world, mode, the scores of bench/scores.py). An entry that learns nothing
(bench/representations.py) has no runs: its rows are computed from the datasets.
"""

from __future__ import annotations

import datetime
import json
import socket
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smspace.bench.representations import REPRESENTATIONS
from smspace.bench.scores import run_scores, scores_of
from smspace.bench.suite import Suite, Task, datasets_hash
from smspace.common.cli import default_workers
from smspace.common.errors import SmspaceError
from smspace.common.progress import duration
from smspace.common.provenance import cpu, git_commit, version
from smspace.lake.dataset import Dataset
from smspace.lake.manifest import dataset_id
from smspace.lake.store import Store, open_store

BENCH = "bench.json"
SCORES = "scores.json"


@dataclass(frozen=True)
class Entry:
    """A model (smspace's, or any package's registered one) with its parameters, or a
    representation that learns nothing."""

    name: str
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def learns(self) -> bool:
        return self.name not in REPRESENTATIONS

    @property
    def folder(self) -> str:
        if not self.params:
            return self.name
        from smspace.study.file import folder_name  # key=value,… as a study's grid names its folders

        return self.name + "," + folder_name(dict(sorted(self.params.items()))).replace("/", "-").replace("\\", "-")

    def record(self) -> dict[str, Any]:
        """What the entry is: a registered model's package and code hash included."""
        record: dict[str, Any] = {"name": self.name, "params": self.params, "learns": self.learns}
        if self.learns:
            from smspace.train.model import plugin_record

            record["plugin"] = plugin_record(self.name)
        return record

    def check(self) -> None:
        """Refused before anything is generated or written: an unknown name, parameters a
        representation does not take."""
        if not self.learns:
            if self.params:
                raise SmspaceError(f"entry {self.name!r} learns nothing and takes no parameters")
            return
        from smspace.train.config import MODELS

        MODELS.get(self.name)


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
    """Every entry on every task (each resumed where it stopped); returns the task folders."""
    for entry in entries:
        entry.check()
    for task in suite.tasks:
        check_task(suite, task)
    lake, out = open_store(lake), open_store(out)
    _check_earlier(suite, entries, out, overwrite)
    done = []
    for task in suite.tasks:  # task by task: a leaderboard fills a column at a time
        _generate(task, lake, gen_workers, executor, notify)  # before any entry: no entry's time includes it
        _check_lake(lake, suite, task)
        for entry in entries:
            folder = _folder(out, suite, task, entry)
            notify(f"bench: {suite.label} {entry.folder} on {task.name}")
            session = _begin(folder, suite, task, entry, workers, executor, overwrite)
            clock = time.monotonic()
            if entry.learns:
                rows = _train(task, entry, lake, folder, workers, gen_workers, executor, overwrite, notify)
            else:
                rows = _represent(task, entry, lake)
            folder.put(SCORES, (json.dumps(rows, indent=1) + "\n").encode())
            _end(folder, session, time.monotonic() - clock)
            done.append(folder)
    return done


def plan_bench(
    suite: Suite, entries: list[Entry], lake: Store | str, out: Store | str, workers: int = 1, overwrite: bool = False
) -> list[str]:
    """What `run_bench` would generate, train and take, as each task's study budgets it (measured
    here and now, study/budget.py), and the whole bench's time. Writes nothing."""
    from smspace.study.file import load_study
    from smspace.study.runner import plan_study

    for entry in entries:
        entry.check()
    for task in suite.tasks:
        check_task(suite, task)
    lake, out = open_store(lake), open_store(out)
    _check_earlier(suite, entries, out, overwrite)
    lines, total_s = [], 0.0
    for task in suite.tasks:
        generate_s = 0.0  # the task's datasets are generated once, whichever entry comes first
        for entry in entries:
            folder = _folder(out, suite, task, entry)
            lines.append(f"{suite.label} {entry.folder} on {task.name}:")
            if not entry.learns:
                lines.append(f"  learns nothing: {task.worlds * len(task.modes)} representations of the regular states")
                continue
            with tempfile.TemporaryDirectory(prefix="smspace-bench-") as tmp:
                path = Path(tmp) / f"{task.name}.toml"
                path.write_text(study_toml(task, entry))
                plan = plan_study(load_study(path), f"task {task.name}", lake, folder, workers, overwrite)
            lines += [f"  {line}" for line in plan.lines[:-1]]  # the last: "nothing was written", said once below
            generate_s, total_s = max(generate_s, plan.generate_s), total_s + plan.train_s
        total_s += generate_s
    lines.append(f"bench: about {duration(total_s)} on {workers} worker(s), at the rates measured now")
    lines.append("dry run: nothing was written")
    return lines


def _folder(out: Store, suite: Suite, task: Task, entry: Entry) -> Store:
    return out.child(suite.label).child(entry.folder).child(task.name)


def _check_lake(lake: Store, suite: Suite, task: Task) -> None:
    """What was trained on is what the suite fixed: each dataset's recorded config hash."""
    for name, expected in task.datasets().items():
        found = Dataset.open(name, lake).manifest.config_hash
        if found != expected:
            raise SmspaceError(
                f"{lake.url}/{name} was generated with config {found}, not the {expected} that suite "
                f"{suite.label} fixes for task {task.name}; use a lake of its own (--lake)"
            )


def _train(
    task: Task, entry: Entry, lake: Store, folder: Store, workers: int, gen_workers: int, executor: str,
    overwrite: bool, notify: Callable[[str], None],
) -> list[dict[str, Any]]:  # fmt: skip
    from smspace.study.runner import run_study

    with tempfile.TemporaryDirectory(prefix="smspace-bench-") as tmp:
        path = Path(tmp) / f"{task.name}.toml"
        path.write_text(study_toml(task, entry))
        runs = run_study(path, lake, folder, overwrite, workers, gen_workers, executor, notify)
    return [run_scores(run) for run in runs]


def _generate(task: Task, lake: Store, gen_workers: int, executor: str, notify: Callable[[str], None]) -> None:
    """The task's datasets, generated (or completed) if missing."""
    from smspace.datagen.generate import generate
    from smspace.datagen.setups import get_setup

    shard = get_setup(task.setup).default_shard_size
    clock = time.monotonic()
    results = generate(
        lake, task.setup, task.modes, task.world_seeds, task.transitions, shard, workers=gen_workers,
        executor=executor, notify=notify,
    )  # fmt: skip
    if any(new for _, new in results):
        notify(f"bench: {task.name}'s datasets generated in {time.monotonic() - clock:.0f} s")


def _represent(task: Task, entry: Entry, lake: Store) -> list[dict[str, Any]]:
    rows = []
    for seed in task.world_seeds:
        for mode in task.modes:
            ds = Dataset.open(dataset_id(task.setup, seed, mode), lake)
            clock = time.monotonic()
            h = REPRESENTATIONS[entry.name](ds, task.n_h, seed)
            wall = time.monotonic() - clock
            _, p = ds.regular_sampling()
            rows.append({"world": seed, "mode": mode, "step": 0, "wall_s": wall, "run": ds.manifest.dataset_id,
                         **scores_of(h, p, seed)})  # fmt: skip
    return rows


def study_toml(task: Task, entry: Entry) -> str:
    """The study a learned entry trains on a task: the task's datasets, its protocol, the entry's model."""
    lines = [
        "[study]",
        f"name = {json.dumps(task.name)}",
        f"setup = {json.dumps(task.setup)}",
        f"modes = {json.dumps(list(task.modes))}",
        f"worlds = {task.worlds}",
        f"seed = {task.seed}",
        f"transitions = {task.transitions}",
        "[train]",
        f"model = {json.dumps(entry.name)}",
        f"steps = {task.steps}",
        f"eval_every = {task.eval_every}",
        f"n_h = {task.n_h}",
    ]
    if entry.params:
        lines.append(f"model_params = {_toml_table(entry.params)}")
    return "\n".join(lines) + "\n"


def _toml_table(params: dict[str, Any]) -> str:
    """An inline TOML table of plain values (JSON's spelling of numbers, strings, lists and
    booleans is TOML's)."""
    return "{" + ", ".join(f"{json.dumps(k)} = {json.dumps(v)}" for k, v in params.items()) + "}"


def _check_earlier(suite: Suite, entries: list[Entry], out: Store, overwrite: bool) -> None:
    """Every earlier result checked before anything is generated or trained."""
    for task in suite.tasks:
        for entry in entries:
            _earlier(_folder(out, suite, task, entry), _terms(suite, task, entry), overwrite)


def _terms(suite: Suite, task: Task, entry: Entry) -> dict[str, Any]:
    return {"suite": suite.name, "version": suite.version, "task": task.protocol(), "entry": entry.record(),
            "datasets": task.datasets()}  # fmt: skip


def _earlier(folder: Store, terms: dict[str, Any], overwrite: bool) -> dict[str, Any] | None:
    """The result already in `folder` (None: none, or --overwrite), refused if it was made on other
    terms (another entry's code, another protocol): its sessions would not describe this result."""
    if overwrite or not folder.exists(BENCH):
        return None
    try:
        before = json.loads(folder.read_bytes(BENCH))
    except ValueError as e:
        raise SmspaceError(f"{folder.url}/{BENCH} is not readable JSON ({e}); --overwrite replaces it") from None
    changed = [key for key, value in terms.items() if before.get(key) != value]
    if changed:
        raise SmspaceError(
            f"{folder.url} holds a result made with another {', '.join(changed)}; "
            "--overwrite replaces it, or give another --out"
        )
    return before


def _begin(folder: Store, suite: Suite, task: Task, entry: Entry, workers: int, executor: str, overwrite: bool) -> int:
    """bench.json with this session in it, its wall time unknown until it ends (a session that
    was interrupted or failed stays so: the leaderboard says the time is incomplete). Returns the
    session's index."""
    terms = _terms(suite, task, entry)
    before = _earlier(folder, terms, overwrite)
    sessions = before.get("sessions", []) if before else []
    session = {"started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "wall_s": None,
               "workers": workers, "executor": executor, "smspace": version("smspace"), "git_commit": git_commit(),
               "host": socket.gethostname(), "cores": default_workers(), **cpu()}  # fmt: skip
    record = terms | {"sessions": [*sessions, session]}
    folder.make()
    folder.put(BENCH, (json.dumps(record, indent=1) + "\n").encode())
    return len(sessions)


def _end(folder: Store, session: int, wall_s: float) -> None:
    record = json.loads(folder.read_bytes(BENCH))
    record["sessions"][session]["wall_s"] = wall_s
    folder.put(BENCH, (json.dumps(record, indent=1) + "\n").encode())
