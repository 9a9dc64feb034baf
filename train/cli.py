"""smtrain: train the sensorimotor predictive network on lake datasets, list and describe runs."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import click

from smspace.common.cli import (
    LAKE_OPTION,
    display_name,
    echo_listing,
    friendly_errors,
)
from smspace.common.completion import complete_datasets
from smspace.common.errors import SmspaceError
from smspace.common.rerun_output import view_options
from smspace.train.config import RUNS
from smspace.train.options import (
    config_from_flags,
    config_options,
    given_fields,
)


@click.command()
@click.argument("dataset", required=False, shell_complete=complete_datasets)
@LAKE_OPTION
@click.option("--out", default=None, help="Run folder, or an fsspec URL [default: runs/<dataset>-nh<N>-seed<S>].")
@config_options()
@click.option(
    "--resume",
    "resume_dir",
    default=None,
    help="Continue the run in this folder from its last checkpoint (--steps may extend it).",
)
@click.option("--overwrite", is_flag=True, help="Replace the run already in --out.")
@click.option(
    "--nproc",
    type=click.IntRange(1, 1024),
    default=1,
    show_default=True,
    help="Train this one run on N processes of this machine (DDP, gloo; rendezvous on 127.0.0.1 only).",
)
@friendly_errors
def fit(dataset, lake, out, resume_dir, overwrite, nproc, **flags) -> None:
    """Train on DATASET (a folder or an id in the lake); prints the final metrics. Under torchrun,
    one run on all its processes (DDP); --batch-size is then the global batch."""
    from smspace.train.fit import fit as run_fit
    from smspace.train.fit import plan_fit
    from smspace.train.launch import launch_if_asked, rank_of

    given = given_fields(click.get_current_context())
    template = config_from_flags(flags)
    say_precision(flags)

    def plan_for(world: int):
        return plan_fit(template, dataset, lake, out, resume_dir, overwrite, given, world)

    launch_if_asked(nproc, plan_for)
    plan = plan_for(int(os.environ.get("WORLD_SIZE", "1") or 1))  # the same on every rank
    with rank_of(plan, lambda line: click.echo(line, err=True)) as (ranks, run):
        result = run_fit(plan.cfg, run, resume=plan.resume, ranks=ranks)
    if ranks.primary:
        click.echo(f"run: {display_name(run.url)}")
        click.echo(json.dumps({k: v for k, v in result.items() if k != "elapsed_s"}))


def say_precision(flags: dict) -> None:
    """--precision auto is decided now, for the runs created now; say what and why."""
    if flags.get("precision") == "auto":
        from smspace.train.precision import resolve

        precision, why = resolve("auto", flags.get("device") or "cpu")
        click.echo(f"--precision auto: {precision} ({why})", err=True)


@click.command()
@click.argument("runs", nargs=-1, required=True)
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Folder for figures and tables.")
@friendly_errors
def report(runs, out) -> None:
    """Draw the paper's figures and the table of final values from run folders."""
    from smspace.train.report import report as run_report

    written, notices = run_report(list(runs), out)
    for line in notices:
        click.echo(line, err=True)
    for path in written:
        click.echo(str(path))


def _listed(folder, name: str) -> dict:
    """A run's summary, or a "broken" row saying why it cannot be read: one bad run hides no other.
    `name`: where the run lies under the listed folder (sub-study/run for a study's runs)."""
    from smspace.lake.scan import descend
    from smspace.lake.store import StorageUnreachable
    from smspace.train.run_dir import RunView

    path = descend(folder, name)
    try:
        summary = RunView.open(path).summary()
    except StorageUnreachable:
        raise  # a frozen endpoint ends the listing, not one "broken" row per run
    except SmspaceError as e:
        empty = dict.fromkeys(("dataset_id", "n_h", "seed", "eval_loss", "d_topo", "d_metric", "elapsed_s", "model",
                               "model_params", "precision"))  # fmt: skip
        where = display_name(str(getattr(path, "url", path)))
        summary = {"run": where, "state": "broken", "message": str(e), "step": 0, "steps": 0} | empty
    study = name.rsplit("/", 1)[0] if "/" in name else ""
    return {"name": display_name(name), "study": display_name(study)} | summary


def _run_names(folder) -> list[str]:
    """Every run folder under `folder`, as its path below it: direct ones, and those of the sweeps,
    studies and grid combinations it holds (as `smtrain report` finds them)."""
    from smspace.lake.scan import folders_holding
    from smspace.train.run_dir import CONFIG

    names = folders_holding(folder, CONFIG, itself=False)
    return sorted(names, key=lambda n: (n.count("/") > 0, n.rsplit("/", 1)[0] if "/" in n else "", n))


def _network(summary: dict) -> str:
    params = summary.get("model_params") or {}
    shown = "(" + ",".join(f"{k}={v}" for k, v in sorted(params.items())) + ")" if params else ""
    return f"{summary.get('model') or '-'}{shown} {summary.get('precision') or ''}".strip()


@click.command("ls")
@click.option(
    "--runs", default=RUNS, show_default=True, help="A folder (or fsspec URL) of run folders, sweeps and studies."
)
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def ls_(runs, as_json) -> None:
    """List the runs under a folder: its own, and those of the sweeps, studies and grid
    combinations in it (grouped by where they lie)."""
    from smspace.lake.store import open_store

    def fmt(v) -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"

    folder = open_store(runs)
    if not folder.is_folder():  # a mistyped name must not look like a folder without runs
        raise SmspaceError(f"no run folders at {folder} (--runs names the folder holding them)")
    rows = [_listed(folder, name) for name in _run_names(folder)]
    width = max([40, *(len(r["name"]) for r in rows)])
    echo_listing(
        rows,
        as_json,
        f"{'run':<{width}} {'state':<11} {'step':>13} {'loss':>10} {'D_topo':>10} {'D_metric':>10}  network",
        lambda s: (
            f"{s['name']:<{width}} {s['state']:<11} {s['step']:>6}/{s['steps']:<6} "
            f"{fmt(s['eval_loss']):>10} {fmt(s['d_topo']):>10} {fmt(s['d_metric']):>10}  {_network(s)}"
        ),
    )


@click.command()
@click.argument("run")
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def info(run, as_json) -> None:
    """Describe one run: config, state, last metrics, and what made it (the software and machine
    of each training session, the software that made its dataset)."""
    from smspace.train.run_dir import RunView

    opened = RunView.open(run)
    cfg = opened.config
    summary = opened.summary() | {"config": cfg.to_dict(), "dataset_software": _dataset_software(cfg.dataset)}
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    for key, value in summary.items():
        if key not in ("config", "dataset_software"):
            click.echo(f"{key:>12}: {value}")
    for i, session in enumerate(cfg.sessions):
        click.echo(f"{'session ' + str(i + 1):>12}: {_session_line(session)}")
    software = summary["dataset_software"]
    shown = ", ".join(f"{k} {v}" for k, v in software.items()) if software else "unknown (dataset not readable here)"
    click.echo(f"{'dataset made':>12}: {shown}")
    click.echo(f"{'config':>12}: {json.dumps({k: v for k, v in summary['config'].items() if k != 'sessions'})}")


def _session_line(session: dict) -> str:
    commit = session.get("git_commit") or ""
    shown = f" ({commit[:12]}{'+dirty' if commit.endswith('+dirty') else ''})" if commit else ""
    return (
        f"{session.get('started')}: smspace {session.get('smspace')}" + shown
        + f", torch {session.get('torch')}, Python {session.get('python')}, {session.get('cpu')} "
        + f"[{' '.join(session.get('cpu_vector_extensions', []))}; torch uses {session.get('torch_cpu_capability')}]"
        + f", device {session.get('device')}, {session.get('threads')} thread(s), host {session.get('host')}"
        + (f", compile: {session['compile']}" if session.get("compile") else "")
    )  # fmt: skip


def _dataset_software(where: str) -> dict | None:
    """The software its manifest records, or None where the dataset cannot be read from here."""
    from smspace.lake.manifest import load_manifest
    from smspace.lake.store import StorageUnreachable

    try:
        return load_manifest(where).software
    except StorageUnreachable:
        raise
    except (SmspaceError, OSError):
        return None


@click.command()
@click.argument("run")
@view_options
@friendly_errors
def view(run, output) -> None:
    """Replay a run in rerun: h coloured by p, the affine projection, curves, predictions."""
    from smspace.train.run_dir import RunView
    from smspace.train.view import view_run

    n = view_run(RunView.open(run), output)
    if output.save:
        click.echo(f"{output.save}\t{n} evaluations")


# grouped into smgen and smtrain by smspace/cli.py
COMMANDS = (fit, report, ls_, info, view)
