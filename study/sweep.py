"""One sweep folder of a study: every (world, mode) run, generated if missing, trained as ensembles.

study/runner.py runs a study request (a file, a bench task, `smtrain sweep`'s flags) as one such
folder per combination of its grid; this module plans and trains the runs of each.

Run folders are the ones `smtrain fit` writes (so ls, info, view, report and fit --resume all work
on them). A sweep re-run continues where it stopped: finished runs are skipped, the others resume
from their checkpoints, grouped by the step they reached.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from smspace.common import plugins
from smspace.common.bounded import run_within
from smspace.common.differing import differing
from smspace.common.errors import SmspaceError
from smspace.common.executors import WorkerDied, open_executor
from smspace.datagen.generate import default_sizes, generate
from smspace.datagen.parts import world_for
from smspace.datagen.setups import get_setup, setup_plugin
from smspace.lake.exploration import Exploration
from smspace.lake.manifest import load_manifest
from smspace.lake.store import Store, exists, listing, open_store, within
from smspace.study.monitor import StudyMonitor, monitored
from smspace.study.record import STUDY, SweepRecord
from smspace.train.config import TrainConfig, available_memory, memory_needed
from smspace.train.contract import check_model
from smspace.train.engine import resolve_device
from smspace.train.fit import train_ensemble
from smspace.train.precision import say_notes_through
from smspace.train.run_dir import CONFIG, RunDir
from smspace.train.terms import HISTORY, grown, study_template, terms


def recorded_study(out: Store) -> dict[str, Any] | None:
    """The terms of the study already in `out`: its study.json, else (a folder of an older smspace)
    the terms its runs share; None for a new study."""
    record = SweepRecord.read(out)
    if record is not None:
        return record.terms
    found: dict[str, dict[str, Any]] = {}
    for path in listing(out, f"*/{CONFIG}"):
        run = RunDir.open(out.child(path.split("/")[0]))
        recorded = run.view.recorded_keys()
        found[run.name] = {k: v for k, v in terms(run.view.config).items() if k in recorded}
    if not found:
        return None
    first_name, first = next(iter(found.items()))
    for name, other in found.items():
        diff = differing(first, other)
        if diff:
            raise SmspaceError(
                f"{out.url} holds runs of several studies ({first_name} and {name} differ in {', '.join(diff)}); "
                "use another --out"
            )
    return first


def study_terms(
    template: TrainConfig, setup: str, transitions: int, out: Store, overwrite: bool, explicit: frozenset[str],
    exploration: dict[str, Any] | None = None,
) -> tuple[TrainConfig, str | None]:  # fmt: skip
    """The template every run of the study trains with (train/terms.py, rule 4), and the line
    saying how the study changed; checked before any dataset is generated. The exploration is a
    term: a folder of transitions runs never takes walk runs."""
    recorded = None if overwrite else recorded_study(out)
    resolved = template.for_setup(setup, transitions, get_setup(setup).encoder_layers, exploration)
    return study_template(recorded, resolved, explicit, out.url)


T = TypeVar("T")


def plan_runs(
    template: TrainConfig, datasets: list[Store], out: Store | Path | str, overwrite: bool
) -> list[tuple[RunDir, int]]:
    """(run folder, step it is at) for every dataset of a planned study. Every run is checked
    before anything is written; then study.json is recorded, new run folders created and
    extended runs record their extension."""
    out = open_store(out)
    manifests = [load_manifest(folder) for folder in datasets]
    cfgs = [replace(template, seed=m.world_seed).for_dataset(f, m) for f, m in zip(datasets, manifests, strict=True)]
    actions: list[tuple[Store, TrainConfig, tuple[RunDir, TrainConfig | None] | None]] = []
    for cfg in cfgs:
        path = out.child(cfg.run_name)
        if overwrite or not exists(path, CONFIG):
            actions.append((path, cfg, None))
            continue
        run = RunDir.open(path)
        old = run.view.config
        recorded = run.view.recorded_keys()  # a field an older smspace did not record is unknown, not different
        diff = differing(old.to_dict(), cfg.to_dict(), ignore=("steps", "run_id", *HISTORY), within=recorded)
        if diff:
            raise SmspaceError(f"{path} holds a run with another {', '.join(diff)}; pass --overwrite or --out")
        # the study's terms were checked: only a run made by hand is shorter than its study
        extension = grown(old.steps, cfg.steps, f"{path} holds a run of {old.steps} steps; this study has {cfg.steps}")
        extended = None
        if extension is not None:
            extended = replace(cfg, run_id=old.run_id, extensions=[*old.extensions, extension])
        actions.append((path, cfg, (run, extended)))
    out.make()
    earlier = None if overwrite else SweepRecord.read(out)
    SweepRecord(terms(cfgs[0]), earlier.ensembles if earlier is not None else ()).write(out)
    plans = []
    for path, cfg, existing in actions:
        if existing is None:
            plans.append((RunDir.create(path, cfg, overwrite), 0))
            continue
        run, extended = existing
        if extended is not None:
            run.write_config(extended)
        step = run.view.checkpoint_step()
        if step == 0:  # killed before its first checkpoint: start it afresh
            run = RunDir.create(path, extended or run.view.config, overwrite=True)
        plans.append((run, step))
    return plans


@dataclass(frozen=True)
class SweepPlan:
    """What one sweep folder holds: the datasets (setup × modes × worlds) and the runs' template."""

    setup: str
    modes: list[str]
    world_seeds: list[int]
    template: TrainConfig
    transitions: int | None = None
    explicit: frozenset[str] = frozenset()
    exploration: Exploration = field(default_factory=Exploration)

    @property
    def n_transitions(self) -> int:
        """The size given, or the setup's default (walks: rounded down to whole episodes)."""
        return default_sizes(self.setup, self.exploration, self.transitions, None)[0]

    @property
    def shard_size(self) -> int:
        return default_sizes(self.setup, self.exploration, self.transitions, None)[1]


def check_terms(study: SweepPlan, out: Store, overwrite: bool) -> tuple[TrainConfig, str | None]:
    """The template the sweep in `out` trains with, and the line that says how its terms change;
    refused before anything is generated if they may not, or if its model breaks its contract."""
    problem = study.exploration.problem(study.n_transitions, study.shard_size)
    if problem is not None:
        raise SmspaceError(f"datasets of {study.setup}: {problem}")
    explored = study.exploration.record()
    template, change = study_terms(
        study.template, study.setup, study.n_transitions, out, overwrite, study.explicit, explored
    )
    check_study_model(template, study.setup, study.world_seeds[0])
    return template, change


def check_apart(out: Store | Path | str, lake: Store | str) -> None:
    """A study's runs never go into its lake: run folders beside (or inside) datasets."""
    if within(out, lake):
        raise SmspaceError(f"--out {out} lies inside the lake {lake}; runs and datasets live apart")


def check_study_model(template: TrainConfig, setup: str, seed: int) -> None:
    """What a run would refuse, refused before any dataset, study record or run folder is written:
    a device this machine lacks, a network that does not fit in memory, then a network that breaks
    its contract on a probe batch (train/contract.py). The world is the one generation's pre-flight
    builds and keeps (datagen/parts.py, world_for)."""
    resolve_device(template.device)
    walk = Exploration.from_record(template.exploration)
    if template.window > 1 and not walk.walks:
        raise SmspaceError(
            f"window: {template.window}; this study generates independent transitions, and windows need walks "
            '(study.exploration = "walk")'
        )
    if template.window > 1 and template.window > walk.length:
        raise SmspaceError(f"window: {template.window} steps do not fit in the study's episodes of {walk.length}")
    world = world_for(setup, seed)
    n_motor, n_sensor = get_setup(setup).n_motor, int(np.prod(world.sensor_shape))
    with plugins.guarded(setup_plugin(setup), f"in regular_sampling() of world {seed}"):
        n_regular = len(world.regular_sampling()[0])
    needed, free = memory_needed(template, n_motor, n_sensor, n_regular, 1), available_memory()
    if needed > free:
        raise SmspaceError(
            f"one run of this study needs about {needed / 2**30:.1f} GiB of memory; "
            f"{free / 2**30:.1f} GiB are available"
        )
    check_model(template, n_motor, n_sensor, stacked=True)


def prepare(
    study: SweepPlan,
    lake: Store | str,
    out: Store | Path | str,
    gen_workers: int,
    max_ensemble: int,
    overwrite: bool,
    workers: int,
    notify: Callable[[str], None],
    checked: TrainConfig | None = None,
) -> tuple[list[RunDir], list[tuple[list[RunDir], bool]]]:
    """Generate the missing datasets and plan the runs: (every run, the ensembles still to train,
    each with whether it resumes). `checked`: the template `check_terms` already returned."""
    out = open_store(out)
    template = checked
    if template is None:
        template, change = check_terms(study, out, overwrite)
        if change:
            notify(change)
    results = generate(
        lake, study.setup, study.modes, study.world_seeds, study.n_transitions, study.shard_size,
        workers=gen_workers, notify=notify, exploration=study.exploration,
    )  # fmt: skip
    datasets = [open_store(lake).child(m.dataset_id) for m, _ in results]
    plans = plan_runs(template, datasets, out, overwrite)
    at = {run.name: step for run, step in plans}
    ensembles_todo = []
    for group in study_ensembles(out, [run for run, _ in plans], max_ensemble, workers):
        todo = [run for run in group if at[run.name] < run.view.config.steps]
        if todo:  # resumed from the step all members reached (train/fit.py, resume_from_folders)
            ensembles_todo.append((todo, min(at[run.name] for run in todo) > 0))
    return [run for run, _ in plans], ensembles_todo


def study_ensembles(out: Store, runs: list[RunDir], max_ensemble: int, workers: int) -> list[list[RunDir]]:
    """The ensembles the runs train in (`planned_ensembles`); new groups are recorded in study.json."""
    record = SweepRecord.read(out)
    if record is None:  # plan_runs records it before any run is trained
        raise SmspaceError(f"{out.url}/{STUDY} is gone: another process removed it while the study ran")
    by_name = {run.name: run for run in runs}
    recorded, new = planned_ensembles(record, list(by_name), max_ensemble, workers)
    if new:
        record.with_ensembles(new).write(out)
    return [[by_name[name] for name in group] for group in recorded + new]


def planned_ensembles(
    record: SweepRecord | None, names: list[str], max_ensemble: int, workers: int
) -> tuple[list[list[str]], list[list[str]]]:
    """(the groups study.json recorded when these runs first trained, new groups for the others):
    a re-run trains the same groups whatever --max-ensemble or --workers say now, so that resuming
    never changes the computation. The sweep and its dry run plan with this one function."""
    wanted = set(names)
    groups = record.ensembles if record is not None else ()
    recorded = [[name for name in group if name in wanted] for group in groups]
    recorded = [group for group in recorded if group]
    grouped = {name for group in recorded for name in group}
    return recorded, ensembles([name for name in names if name not in grouped], max_ensemble, workers)


def ensembles(runs: list[T], max_ensemble: int, workers: int) -> list[list[T]]:
    """Runs cut into ensembles of at most max_ensemble, and into at least `workers` of them when
    there are enough runs, so that every core (or Ray CPU) gets one. A run's weights do not depend
    on the grouping (docs/MODEL.md §4: only the summation order of the batched matmuls differs)."""
    size = max(1, min(max_ensemble, -(-len(runs) // max(1, workers))))
    return [runs[i : i + size] for i in range(0, len(runs), size)]


def train_one_ensemble(paths: list[str], resume: bool, threads: int, channel: Any = None, key: str = "") -> int:
    """One ensemble, wherever it runs (this process, a spawned one, a Ray worker); returns its size.
    Its step goes on `channel` about every second (study/monitor.py)."""
    runs = [RunDir.open(p) for p in paths]
    if channel is not None:
        say_notes_through(lambda line: _put(channel, (key, line)))
    train_ensemble(runs, resume=resume, threads=threads, progress=False, on_step=_reporter(channel, key))
    return len(runs)


def _reporter(channel: Any, key: str) -> Callable[[int], None] | None:
    """Puts the step on the channel; progress is a courtesy: if the channel is gone (its manager
    process killed), training goes on unreported."""
    if channel is None:
        return None
    alive = [True]

    def report(step: int) -> None:
        if alive[0]:
            alive[0] = _put(channel, (key, step))

    return report


def _put(channel: Any, message: tuple[str, int | str]) -> bool:
    """False when the channel is gone (its manager process killed): progress is a courtesy."""
    try:
        channel.put(message)
    except Exception:  # a dead manager raises several kinds (EOFError, ConnectionError, OSError…)
        return False
    return True


def _mark_stopped(runs: list[RunDir], state: str, line: str) -> None:
    """The runs a dead worker (or its killed siblings, or an interrupted sweep) left "running" say
    why they stopped."""

    def mark(run: RunDir) -> None:
        now = RunDir.open(run.store)
        state_now = now.view.status().state
        # "created" with a checkpoint: its worker was stopped between the first checkpoint and the
        # status written after it (seen under load); one with none never started and stays so
        if state_now in ("running", "stale") or (state_now == "created" and now.view.has_checkpoint()):
            run.set_status(state, now.view.checkpoint_step(), line)  # the step it resumes from

    run_within([lambda run=run: mark(run) for run in runs])


def run_ensembles(
    ensembles_todo: list[tuple[list[RunDir], bool]], executor: str, workers: int, threads: int, device: str
) -> None:
    """Train every ensemble where the executor puts it (common/executors.py): in this process for
    one worker, else one spawned process per ensemble up to `workers` at a time, or a Ray task
    each (never retried by Ray: a task started again would not know how far it got; re-running
    the sweep resumes). The study's progress is one line (study/monitor.py)."""
    if not ensembles_todo:
        return
    for runs, _ in ensembles_todo:  # whoever trains them claims them, this process included
        for run in runs:
            run.release()
    starts = {str(i): (len(runs), _start_step(runs) if resume else 0, runs[0].view.config.steps)
              for i, (runs, resume) in enumerate(ensembles_todo)}  # fmt: skip
    gpus = 1 if device.startswith("cuda") else 0
    try:
        with open_executor(executor, workers, num_cpus=threads, num_gpus=gpus, max_retries=0) as ex, ex.channel() as ch:
            tasks = [
                ([run.url for run in runs], resume, threads, ch, str(i))
                for i, (runs, resume) in enumerate(ensembles_todo)
            ]
            with monitored(StudyMonitor(starts), ch):
                for _ in ex.map(train_one_ensemble, tasks):
                    pass
    except WorkerDied as e:
        line = f"{e}; the runs keep their last checkpoints: the same command resumes them"
        _mark_stopped([run for runs, _ in ensembles_todo for run in runs], "failed", line)
        raise WorkerDied(line) from None
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the workers were killed mid-step, as a lone fit is
        line = "interrupted; the checkpoint of its last evaluation is kept: the same sweep resumes it"
        _mark_stopped([run for runs, _ in ensembles_todo for run in runs], "interrupted", line)
        raise


def _start_step(runs: list[RunDir]) -> int:
    """The step a resumed ensemble starts from: the last checkpoint all its members reached."""
    return min(run.view.checkpoint_step() for run in runs)
