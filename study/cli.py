"""`smtrain sweep`: the command that composes generation and training (a sweep generates the
datasets it trains on), so it lives above both: `smtrain` is train/cli.py's group with this command
added, and nothing in train/ imports the generators or the studies (tests/test_layout.py)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from smspace.common.cli import (
    DEFAULT_MAX_ENSEMBLE,
    LAKE_OPTION,
    MAX_ENSEMBLE,
    MAX_WORKERS,
    display_name,
    executor_option,
    friendly_errors,
    on_interrupt,
)
from smspace.common.errors import SmspaceError
from smspace.datagen import options as generation
from smspace.train.cli import say_precision
from smspace.train.config import RUNS, flag_fields, flag_name
from smspace.train.options import config_from_flags, config_options, given_fields, on_command_line
from smspace.train.run_dir import RunDir


@click.command()
@click.argument("study_file", required=False, type=click.Path(path_type=Path))
@click.argument("overrides", nargs=-1)
@generation.setup_option()
@generation.modes_option("--modes", "modes", default="MEM,MM,MME", show_default=True)
@generation.worlds_option(default=50)
@generation.first_seed_option("first_world", help="First world seed; a run's seed is its world's.")
@generation.transitions_option()
@generation.exploration_options
@generation.generator_workers_option("--gen-workers", "gen_workers")
@LAKE_OPTION
@click.option(
    "--out", default=None, help="Folder (or fsspec URL) for the run folders [default: runs, or runs/<study name>]."
)
@config_options(exclude=("seed",))
@click.option(
    "--max-ensemble",
    type=click.IntRange(1, MAX_ENSEMBLE),
    default=DEFAULT_MAX_ENSEMBLE,
    show_default=True,
    help="Runs per vectorised model.",
)
@click.option("--overwrite", is_flag=True, help="Replace runs in --out made with another config.")
@executor_option("ensembles train")
@click.option(
    "--workers",
    type=click.IntRange(1, MAX_WORKERS),
    default=None,
    help="Ensembles trained at once (processes, or CPUs of a local Ray) [default: this machine's cores].",
)
@click.option(
    "--dry-run", is_flag=True, help="With a study file: what it would generate, train, store and take; writes nothing."
)
@friendly_errors
def sweep(
    study_file,
    overrides,
    setup_name,
    modes,
    worlds,
    first_world,
    transitions,
    exploration,
    walk_length,
    walk_step,
    gen_workers,
    lake,
    out,
    max_ensemble,
    overwrite,
    executor,
    workers,
    dry_run,
    **flags,
) -> None:
    """Generate missing datasets, then train every (world, mode) run as vectorised ensembles: from
    flags, or from STUDY_FILE (TOML: docs/STUDIES.md), which may also vary any training field;
    OVERRIDES (section.key=value, e.g. train.steps=2000 grid.n_h=[3,5]) apply on top of the file."""
    from smspace.common.cli import default_workers
    from smspace.datagen.setups import get_setup
    from smspace.lake.dataset import lake_store
    from smspace.lake.transitions import parse_modes
    from smspace.study.file import StudyRequest
    from smspace.study.runner import dry_run as plan_only
    from smspace.study.runner import run_study
    from smspace.train.engine import resolve_device

    ctx = click.get_current_context()
    if study_file is not None and "=" in study_file.name and not study_file.exists():  # an override, no file
        overrides, study_file = (str(study_file), *overrides), None
    if study_file is not None:
        _study_command(ctx, study_file, overrides, lake, out, overwrite, executor, workers, gen_workers, dry_run)
        return
    if overrides:
        raise SmspaceError(f"{overrides[0]}: overrides apply to a study file (smtrain sweep STUDY.toml KEY=VALUE…)")
    if setup_name is None:
        raise SmspaceError("give a study file or --setup (smtrain sweep --help)")
    get_setup(setup_name)
    generation.check_seed_range(first_world, worlds)
    mode_list = parse_modes(modes)
    template = config_from_flags(flags)
    say_precision(flags)
    resolve_device(template.device)
    out = out or RUNS
    given = {name: getattr(template, name) for name in given_fields(ctx)}
    run = {"workers": workers or default_workers(), "gen_workers": gen_workers or default_workers(),
           "max_ensemble": max_ensemble, "executor": executor}  # fmt: skip
    walk = {"exploration": exploration}  # the walk flags given, as a study file's keys (checked alike)
    walk |= {key: value for key, value in (("walk_length", walk_length), ("walk_step", walk_step))
             if on_command_line(ctx, key)}  # fmt: skip
    request = StudyRequest.from_flags(setup_name, mode_list, worlds, first_world, transitions, given, run, walk)
    if dry_run:  # budgeted as a study file is
        for line in plan_only(request, lake_store(lake), out, workers, overwrite):
            click.echo(line)
        return
    message = (
        f"interrupted; the runs in {out} keep their last checkpoints and the lake its complete parts: "
        "the same command resumes them"
    )
    with on_interrupt(message):
        runs = run_study(request, lake_store(lake), out, overwrite, notify=lambda line: click.echo(line, err=True))
    _echo_finals(runs)


def _echo_finals(runs: list[RunDir]) -> None:
    """One line per run, as a lone fit ends: where it is, then its last evaluation (JSON)."""
    for run in runs:
        last = run.view.summary()
        shown = {k: last[k] for k in ("state", "step", "eval_loss", "d_topo", "d_metric")}
        click.echo(f"{display_name(run.url)}\t{json.dumps(shown)}")


STUDY_FILE_KEYS = ("setup_name", "modes", "worlds", "first_world", "transitions", "exploration", "walk_length",
                   "walk_step", "max_ensemble")  # fmt: skip


def _study_command(ctx, study_file, overrides, lake, out, overwrite, executor, workers, gen_workers, dry_run) -> None:
    """`smtrain sweep STUDY.toml`: what the study computes comes from the file alone."""
    from smspace.lake.dataset import lake_store
    from smspace.study.runner import dry_run as plan_only
    from smspace.study.runner import run_study

    given = [p.opts[0] for p in ctx.command.params if p.name in STUDY_FILE_KEYS and on_command_line(ctx, p.name)]
    given += [flag_name(f) for f in flag_fields() if f.name in given_fields(ctx)]
    if given:
        raise SmspaceError(f"{', '.join(given)}: set in the study file {study_file}, not on the command line")
    if dry_run:
        for line in plan_only(study_file, lake_store(lake), out, workers, overwrite, overrides):
            click.echo(line)
        return
    ex = executor if on_command_line(ctx, "executor") else None
    with on_interrupt(
        f"interrupted; the study's runs keep their last checkpoints: smtrain sweep {study_file} resumes them"
    ):
        runs = run_study(
            study_file, lake_store(lake), out, overwrite, workers, gen_workers, ex,
            notify=lambda line: click.echo(line, err=True), overrides=overrides,
        )  # fmt: skip
    _echo_finals(runs)


# grouped into smgen and smtrain by smspace/cli.py
COMMANDS = (sweep,)
