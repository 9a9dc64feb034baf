"""`smtrain sweep STUDY.toml`: a study file run as one sweep per combination of its grid, all
ensembles trained together, or (--dry-run) what it would do, need and take, with nothing written.

Layout: OUT/study-file.toml (the file as given), OUT/study-file.json (resolved), and the runs in
OUT itself without a grid, else in OUT/<key=value,...>/, each an ordinary sweep folder.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from smspace.common.cli import DEFAULT_MAX_ENSEMBLE, default_workers
from smspace.common.errors import SmspaceError, one_line
from smspace.common.executors import import_ray
from smspace.common.main_guard import refuse_unguarded
from smspace.common.progress import duration
from smspace.datagen.generate import check_disk
from smspace.datagen.setups import get_setup
from smspace.lake.exploration import Exploration
from smspace.lake.manifest import dataset_id
from smspace.lake.records import STUDY_FILE, MalformedRecord
from smspace.lake.store import Store, exists, free_bytes, open_store
from smspace.study import budget
from smspace.study.budget import SetupProbe, makespan
from smspace.study.file import RECORD, SOURCE, StudyFile, StudyRequest, changes, folder_name
from smspace.study.record import SweepRecord
from smspace.study.sweep import (
    SweepPlan,
    check_apart,
    check_terms,
    planned_ensembles,
    prepare,
    run_ensembles,
)
from smspace.train.config import RUNS, TrainConfig, flag_fields, parameter_count
from smspace.train.run_dir import CONFIG, RunDir, RunView
from smspace.train.terms import terms


@dataclass(frozen=True)
class Combination:
    values: dict[str, Any]
    out: Store
    plan: SweepPlan


def combinations(study: StudyFile, out: Store) -> list[Combination]:
    found = []
    for values in study.combinations():
        name = folder_name(values)
        plan = SweepPlan(
            study.setup_of(values),
            study.modes,
            study.world_seeds,
            study.config(values),
            study.transitions,
            study.given(values),
            study.exploration_of(study.setup_of(values)),
        )
        found.append(Combination(values, out.child(name) if name else out, plan))
    _refuse_the_same_runs_twice(found)
    return found


def _refuse_the_same_runs_twice(combos: list[Combination]) -> None:
    """Two combinations whose templates resolve to the same terms (precision "auto" decided as the
    "fp32" beside it, say) would train the same runs twice, which a report then refuses to pool."""
    seen: dict[str, Combination] = {}
    for combo in combos:
        key = json.dumps([combo.plan.setup, terms(combo.plan.template)], sort_keys=True, default=str)
        if key in seen:
            first = seen[key]
            asked = first.values.get("precision"), combo.values.get("precision")
            resolved = combo.plan.template.precision
            why = f" (precision {asked[0]} and {asked[1]} both train in {resolved} here)" if len(set(asked)) > 1 else ""
            raise SmspaceError(
                f"grid combinations {folder_name(first.values)} and {folder_name(combo.values)} train the same "
                f"runs{why}; remove one"
            )
        seen[key] = combo


def run_study(
    request: StudyRequest | Path | str,
    lake: Store,
    out: Store | str | None,
    overwrite: bool = False,
    workers: int | None = None,
    gen_workers: int | None = None,
    executor: str | None = None,
    notify: Callable[[str], None] = lambda line: None,
    overrides: Sequence[str] = (),
) -> list[RunDir]:
    """Run (or resume, or extend) a study (a request, or the path of a study file); arguments given
    here override its [run] section, `overrides` (section.key=value) any of a file's keys."""
    request = as_request(request, overrides)
    study, path = request.study, request.where
    out = open_store(out if out is not None else f"{RUNS}/{study.name}")
    workers = workers or study.run.get("workers") or default_workers()
    gen_workers = gen_workers or study.run.get("gen_workers", workers)
    executor = executor or study.run.get("executor", "local")
    max_ensemble = study.run.get("max_ensemble", DEFAULT_MAX_ENSEMBLE)
    if executor == "local" and max(workers, gen_workers) > 1:
        refuse_unguarded(f"smspace.run_study(workers={workers})")
    check_apart(out, lake)
    if executor == "ray":
        import_ray()  # a missing Ray is said before any dataset is generated
    combos = combinations(study, out)
    checked = [_checked(path, c, overwrite) for c in combos]  # every refusal before any write
    _refuse_what_the_lake_cannot_hold(lake, study, combos)
    for line in study_changes(request, out, overwrite):
        notify(line)
    for _, change in checked:
        if change:
            notify(change)
    out.make()
    if request.source is not None:  # flags have no file: each sweep folder's study.json is their record
        out.put(SOURCE, request.source)
        STUDY_FILE.write(out, _resolved(study, combos, checked))
    runs, ensembles_todo = [], []
    for combo, (template, _) in zip(combos, checked, strict=True):
        got, todo = prepare(
            combo.plan, lake, combo.out, gen_workers, max_ensemble, overwrite, workers, notify, checked=template
        )
        runs += got
        ensembles_todo += todo
    first = combos[0].plan.template
    run_ensembles(ensembles_todo, executor, workers, first.threads, first.device)
    return runs


def as_request(request: StudyRequest | Path | str, overrides: Sequence[str] = ()) -> StudyRequest:
    """A request as given, or the one a study file's path (and its overrides) describes."""
    if isinstance(request, StudyRequest):
        if overrides:
            raise SmspaceError(f"{overrides[0]}: overrides apply to a study file, not to {request.where}")
        return request
    return StudyRequest.from_file(request, overrides)


def _resolved(study: StudyFile, combos: list[Combination], checked: list[tuple[TrainConfig, str | None]]) -> dict:
    """The study as recorded: the file's sections, and each combination as it trains (its setup,
    every training flag with the defaults and the setup's network filled in)."""
    resolved = [
        {"folder": folder_name(c.values), "setup": c.plan.setup,
         "train": {f.name: getattr(template, f.name) for f in flag_fields()}}
        for c, (template, _) in zip(combos, checked, strict=True)
    ]  # fmt: skip
    return study.to_dict() | {"combinations": resolved}


def _checked(path: Path | str, combo: Combination, overwrite: bool) -> tuple[TrainConfig, str | None]:
    """check_terms, its refusal naming the study file and the combination it is about."""
    try:
        return check_terms(combo.plan, combo.out, overwrite)
    except SmspaceError as e:
        at = folder_name(combo.values)
        raise type(e)(f"{path}: {f'[{at}] ' if at else ''}{e}") from e


def study_changes(request: StudyRequest, out: Store, overwrite: bool) -> list[str]:
    """What changed since the study file last ran in `out` (nothing for a new folder, --overwrite
    or a study given by flags, whose terms each sweep folder's study.json holds)."""
    study = request.study
    if overwrite or request.source is None:
        return []
    try:
        recorded = STUDY_FILE.read(out)
    except FileNotFoundError:
        return []
    except MalformedRecord as e:  # (another smspace's format is said as it is: --overwrite is no advice)
        raise SmspaceError(f"{out.url}/{RECORD} is unreadable ({e.reason}); pass --overwrite") from None
    try:
        diff = changes(recorded, study.to_dict())
        before = None
        if isinstance(recorded.get("grid"), dict) and all(isinstance(v, list) for v in recorded["grid"].values()):
            before = StudyFile(**{k: recorded[k] for k in study.to_dict() if k in recorded})
            before_names = [folder_name(c) for c in before.combinations()]
    except (AttributeError, KeyError, TypeError, ValueError) as e:  # a record edited by hand
        raise SmspaceError(
            f"{out.url}/{RECORD} is unreadable ({one_line(e, with_type=True)}); pass --overwrite"
        ) from None
    if recorded.get("name") != study.name:  # another study's folder, not this one's past
        raise SmspaceError(
            f"{out.url} holds the study {recorded.get('name')!r}, not {study.name!r}: choose another --out "
            "(or --overwrite to replace it)"
        )
    if not diff:
        return []
    lines = [f"the study in {out.url} changed since it last ran: {'; '.join(diff)}"]
    if before is not None:
        now = {folder_name(c) for c in study.combinations()}
        gone = [name or "(the runs without a grid)" for name in before_names if name not in now]
        if gone:
            lines.append(f"no longer in the study (their runs are kept, not trained): {', '.join(gone)}")
    return lines


# --- the dry run --------------------------------------------------------------------------------


def dry_run(
    request: StudyRequest | Path | str,
    lake: Store,
    out: Store | str | None,
    workers: int | None = None,
    overwrite: bool = False,
    overrides: Sequence[str] = (),
) -> list[str]:
    """The lines of a dry run: datasets to generate, runs (new / to resume / finished), the disk
    they need and the time they take at rates measured here and now. Writes nothing."""
    request = as_request(request, overrides)
    out = out if out is not None else f"{RUNS}/{request.study.name}"
    return plan_study(request, lake, out, workers, overwrite).lines


@dataclass(frozen=True)
class Plan:
    """A study's dry run: its lines, and the seconds they budget (a benchmark adds them up)."""

    lines: list[str]
    generate_s: float
    train_s: float  # starting processes included


def plan_generation(
    setup: str, world_seeds: Sequence[int], modes: Sequence[str], n: int, lake: Store, gen_workers: int,
    probe: SetupProbe | None = None, exploration: Exploration | None = None,
) -> tuple[float, float, str]:  # fmt: skip
    """(seconds, bytes, a line saying so) to generate the datasets of `setup` the lake lacks, at the
    rates measured here and now."""
    spec = get_setup(setup)
    probe = probe or SetupProbe.of(setup, world_seeds[0], modes[0])
    suffix = (exploration or Exploration()).suffix
    ids = [dataset_id(setup, seed, mode) + suffix for seed in world_seeds for mode in modes]
    missing = [i for i in ids if not exists(lake.child(i), "manifest.json")]
    parts = len(missing) * -(-n // spec.default_shard_size)
    lanes = max(1, min(gen_workers, parts))
    worlds_to_build = len({i.rsplit("-", 1)[0] for i in missing})  # each worker builds the worlds it draws from
    seconds = len(missing) * n / probe.gen_rate / lanes + -(-worlds_to_build // lanes) * probe.world_s
    seconds += budget.process_start_s() if lanes > 1 else 0.0  # a pool's start
    size = len(missing) * n * probe.bytes_per_transition
    line = (
        f"datasets of {setup}: {len(ids)}, {len(ids) - len(missing)} in {lake.url}, {len(missing)} to generate "
        f"({len(missing) * n} transitions, about {_size(size)} at "
        f"{probe.bytes_per_transition:.3g} bytes each, {duration(seconds)} at {probe.gen_rate:.4g} transitions/s "
        "per worker, both measured now)"
    )
    return seconds, size, line


def plan_study(
    request: StudyRequest, lake: Store, out: Store | str, workers: int | None = None, overwrite: bool = False
) -> Plan:
    """What run_study would do with `request`, budgeted, with nothing written."""
    study, path = request.study, request.where
    out = open_store(out)
    workers = workers or study.run.get("workers") or default_workers()
    gen_workers = study.run.get("gen_workers", workers)
    max_ensemble = study.run.get("max_ensemble", DEFAULT_MAX_ENSEMBLE)
    check_apart(out, lake)
    combos = combinations(study, out)
    for combo in combos:
        _checked(path, combo, overwrite)  # what a real run would refuse
    _refuse_what_the_lake_cannot_hold(lake, study, combos)
    setups = list(dict.fromkeys(combo.plan.setup for combo in combos))
    worlds = f"{study.seed}..{study.seed + study.worlds - 1}"
    lines = [
        f"study {study.name} ({path}): setup {', '.join(setups)}, modes {','.join(study.modes)}, worlds {worlds}, "
        f"{len(combos)} combination(s), into {out.url}"
    ]
    lines += study_changes(request, out, overwrite)
    probes = {setup: SetupProbe.of(setup, study.seed, study.modes[0]) for setup in setups}
    spawn_s = budget.process_start_s()  # this command's own start, and each spawned worker's
    gen_s = gen_bytes = 0.0
    for setup in setups:
        plan = next(c.plan for c in combos if c.plan.setup == setup)
        seconds, size, line = plan_generation(
            setup, study.world_seeds, study.modes, plan.n_transitions, lake, gen_workers, probes[setup],
            plan.exploration,
        )  # fmt: skip
        gen_s, gen_bytes = gen_s + seconds, gen_bytes + size
        lines.append(line)
    total_bytes = 0
    ensembles_s: list[float] = []
    counts = {"new": 0, "resume": 0, "finished": 0}
    for combo in combos:
        setup = combo.plan.setup
        spec, probe = get_setup(setup), probes[setup]
        explored, n = combo.plan.exploration, combo.plan.n_transitions
        template = combo.plan.template.for_setup(setup, n, spec.encoder_layers, explored.record())
        record = None if overwrite else SweepRecord.read(combo.out)
        states = {
            name: _run_state(combo.out, name, template.steps, overwrite)
            for name in (
                replace(template, dataset_id=dataset_id(setup, seed, mode) + explored.suffix, seed=seed).run_name
                for seed in study.world_seeds
                for mode in study.modes
            )
        }
        for state, _ in states.values():
            counts[state] += 1
        run_steps = sum(template.steps - step for state, step in states.values() if state != "finished")
        recorded, new = planned_ensembles(record, list(states), max_ensemble, workers)
        todo = [g for g in (recorded + new) if any(states[name][0] != "finished" for name in g)]
        slower = budget.contention(min(workers, len(todo)), template.threads)
        costs = {size: budget.ensemble_cost(template, spec.n_motor, probe, size) for size in {len(g) for g in todo}}
        combo_s = []
        for group in todo:
            start = min(states[name][1] for name in group)  # an ensemble resumes at its members' last common step
            left = template.steps - start
            evaluations = left // template.eval_every + (start == 0) + (left % template.eval_every > 0)
            cost = costs[len(group)]
            combo_s.append(slower * (left * cost.step_s + evaluations * cost.evaluation_s))
        ensembles_s += combo_s
        params = parameter_count(template, spec.n_motor, probe.n_sensor)
        per_run = 2 * 12 * params + (template.steps // template.eval_every + 2) * 4 * (
            probe.n_regular * (template.n_h + 2) + 16 * probe.n_sensor
        )
        total_bytes += per_run * sum(state == "new" for state, _ in states.values())
        label = folder_name(combo.values) or "(no grid)"
        sizes = "/".join(str(n) for n in sorted({len(g) for g in todo})) or "-"
        step_ms = max((c.step_s / size for size, c in costs.items()), default=0.0) * 1e3
        lines.append(
            f"  {label}: {len(states)} runs, {run_steps} run-steps to train in {len(todo)} ensemble(s) of {sizes} "
            f"({step_ms:.3g} ms per run-step measured now), {duration(sum(combo_s))} of worker time"
        )
    pool = workers > 1 and len(ensembles_s) > 1  # a pool of spawned workers, each started once; else this process
    total_s = makespan(ensembles_s, workers) + (spawn_s if pool else 0.0)
    _refuse_what_run_folders_cannot_hold(out, total_bytes)
    lines.append(f"runs: {counts['new']} new, {counts['resume']} to resume, {counts['finished']} finished")
    lines.append(f"disk: about {_size(gen_bytes)} in the lake and {_size(total_bytes)} of run folders")
    lines.append(
        f"time: about {duration(spawn_s + gen_s + total_s)} ({duration(gen_s)} generating, {duration(total_s)} "
        f"training on {workers} worker(s), {duration(spawn_s)} starting)"
    )
    lines.append("dry run: nothing was written")
    return Plan(lines, gen_s, spawn_s + total_s)


def _refuse_what_the_lake_cannot_hold(lake: Store, study: StudyFile, combos: list[Combination]) -> None:
    """Generation's own disk check (datagen/generate.py), made before the study writes its records:
    the run and its dry run refuse alike."""
    for setup in dict.fromkeys(c.plan.setup for c in combos):
        plan = next(c.plan for c in combos if c.plan.setup == setup)
        check_disk(lake, setup, study.modes, study.world_seeds, plan.n_transitions, plan.exploration)


def _refuse_what_run_folders_cannot_hold(out: Store, run_bytes: float) -> None:
    """A budget of what cannot be stored is no plan: run folders would fill their disk part-way.
    Object storage has no such limit."""
    out_free = free_bytes(out)
    if out_free is not None and run_bytes > out_free:
        raise SmspaceError(
            f"this study needs about {_size(run_bytes)} of run folders; "
            f"the disk of {out.url} has {_size(out_free)} free"
        )


def _run_state(out: Store, name: str, steps: int, overwrite: bool) -> tuple[str, int]:
    """What the sweep will do with a run: create it (new; a run killed before its first checkpoint
    is created afresh too, as plan_runs does), resume it from its step, or leave it (finished)."""
    where = out.child(name)
    if overwrite or not exists(where, CONFIG):
        return "new", 0
    step = RunView.open(where).checkpoint_step()
    if step == 0:
        return "new", 0
    return ("finished", step) if step >= steps else ("resume", step)


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    raise AssertionError("unreachable")
