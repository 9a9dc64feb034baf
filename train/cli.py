"""smtrain: train the sensorimotor predictive network on lake datasets, list and describe runs."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

from datagen.cliutil import LAKE_OPTION, friendly_errors
from datagen.errors import SmspaceError
from datagen.rerun_output import view_options

RUNS = Path("runs")


def int_list(ctx, param, value: str | None) -> list[int] | None:
    if value is None:
        return None
    try:
        sizes = [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated layer sizes, got {value!r}") from None
    if not sizes or min(sizes) <= 0:
        raise click.BadParameter(f"expected positive layer sizes, got {value!r}")
    return sizes


@click.group(name="smtrain", context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="smspace")
def main() -> None:
    """Train and inspect sensorimotor predictive networks."""


CONFIG_FLAGS = (
    "steps",
    "batch_size",
    "nh",
    "encoder_layers",
    "predictor_layers",
    "lr_start",
    "lr_end",
    "lr_decay_steps",
    "eval_every",
    "seed",
    "device",
    "threads",
    "loader_workers",
)


@main.command()
@click.argument("dataset", required=False)
@LAKE_OPTION
@click.option(
    "--out", type=click.Path(path_type=Path), default=None, help="Run folder [default: runs/<dataset>-nh<N>-seed<S>]."
)
@click.option("--steps", type=click.IntRange(min=1), default=100_000, show_default=True)
@click.option("--batch-size", type=click.IntRange(min=1), default=100, show_default=True)
@click.option("--nh", type=click.IntRange(min=1), default=3, show_default=True, help="Dimension of h.")
@click.option("--encoder-layers", callback=int_list, help="e.g. 150,100,50 [default: the paper's for N_m].")
@click.option("--predictor-layers", callback=int_list, help="[default: 200,150,100]")
@click.option("--lr-start", type=float, default=1e-3, show_default=True)
@click.option("--lr-end", type=float, default=1e-5, show_default=True)
@click.option("--lr-decay-steps", type=click.IntRange(min=0), default=0, help="[default: 80% of --steps]")
@click.option("--eval-every", type=click.IntRange(min=1), default=1000, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--device", default="cpu", show_default=True, help="cpu or cuda")
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True, help="torch CPU threads.")
@click.option("--loader-workers", type=click.IntRange(min=0), default=0, show_default=True)
@click.option(
    "--resume",
    "resume_dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Continue the run in this folder from its last checkpoint.",
)
@click.option("--overwrite", is_flag=True, help="Replace the run already in --out.")
@friendly_errors
def fit(dataset, lake, out, resume_dir, overwrite, **flags) -> None:
    """Train on DATASET (a folder or an id in the lake); prints the final metrics."""
    from datagen.lake.dataset import Dataset
    from train.config import TrainConfig
    from train.fit import fit as run_fit
    from train.run_dir import RunDir

    ctx = click.get_current_context()
    if resume_dir is not None:
        given = [
            f"--{k.replace('_', '-')}"
            for k in CONFIG_FLAGS
            if ctx.get_parameter_source(k) == click.core.ParameterSource.COMMANDLINE and k != "steps"
        ]
        if dataset or given or overwrite:
            raise SmspaceError(f"--resume continues a run with its own config; drop {' '.join(given) or 'DATASET'}")
        run = RunDir.open(resume_dir)
        cfg = run.config
        if ctx.get_parameter_source("steps") == click.core.ParameterSource.COMMANDLINE:
            cfg.steps = flags["steps"]  # extending a run is allowed; the schedule stays as recorded
        result = run_fit(cfg, run, resume=True)
    else:
        if dataset is None:
            raise SmspaceError("DATASET is required (or --resume RUN_DIR)")
        ds = Dataset.open(dataset, lake)
        cfg = TrainConfig(
            dataset=str(ds.folder.resolve()),
            dataset_id=ds.manifest.dataset_id,
            dataset_config_hash=ds.manifest.config_hash,
            steps=flags["steps"],
            batch_size=flags["batch_size"],
            n_h=flags["nh"],
            encoder_layers=flags["encoder_layers"] or [],
            predictor_layers=flags["predictor_layers"] or [200, 150, 100],
            lr_start=flags["lr_start"],
            lr_end=flags["lr_end"],
            lr_decay_steps=flags["lr_decay_steps"],
            eval_every=flags["eval_every"],
            seed=flags["seed"],
            device=flags["device"],
            threads=flags["threads"],
            loader_workers=flags["loader_workers"],
        )
        from train.fit import resolve_device

        resolve_device(cfg.device)
        out = out or RUNS / f"{ds.manifest.dataset_id}-nh{cfg.n_h}-seed{cfg.seed}"
        run = RunDir.create(out, cfg, overwrite)
        result = run_fit(cfg, run)
    click.echo(f"run: {run.path}")
    click.echo(json.dumps({k: v for k, v in result.items() if k != "elapsed_s"}))


@main.command()
@click.option("--setup", "setup_name", required=True, help="grid, grid6, arm, arm6")
@click.option("--modes", default="MEM,MM,MME", show_default=True)
@click.option("--worlds", type=click.IntRange(min=1), default=50, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="First world seed.")
@click.option("--transitions", type=click.IntRange(min=1), default=None, help="[setup default]")
@click.option("--gen-workers", type=click.IntRange(min=1), default=1, show_default=True)
@LAKE_OPTION
@click.option("--out", type=click.Path(path_type=Path), default=RUNS, show_default=True)
@click.option("--steps", type=click.IntRange(min=1), default=100_000, show_default=True)
@click.option("--batch-size", type=click.IntRange(min=1), default=100, show_default=True)
@click.option("--nh", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--encoder-layers", callback=int_list, help="[default: the paper's for N_m]")
@click.option("--predictor-layers", callback=int_list, help="[default: 200,150,100]")
@click.option("--eval-every", type=click.IntRange(min=1), default=1000, show_default=True)
@click.option("--device", default="cpu", show_default=True)
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True)
@click.option(
    "--max-ensemble", type=click.IntRange(min=1), default=150, show_default=True, help="Runs per vectorised model."
)
@click.option("--overwrite", is_flag=True, help="Replace runs in --out made with another config.")
@friendly_errors
def sweep(
    setup_name,
    modes,
    worlds,
    seed,
    transitions,
    gen_workers,
    lake,
    out,
    steps,
    batch_size,
    nh,
    encoder_layers,
    predictor_layers,
    eval_every,
    device,
    threads,
    max_ensemble,
    overwrite,
) -> None:
    """Generate missing datasets, then train every (world, mode) run as vectorised ensembles."""
    from datagen.lake.dataset import default_lake
    from datagen.setups import check_mode, get_setup
    from train.config import TrainConfig
    from train.fit import resolve_device
    from train.sweep import sweep as run_sweep

    get_setup(setup_name)
    mode_list = [check_mode(m.strip()) for m in modes.split(",") if m.strip()]
    resolve_device(device)
    template = TrainConfig(
        dataset="",
        steps=steps,
        batch_size=batch_size,
        n_h=nh,
        encoder_layers=encoder_layers or [],
        predictor_layers=predictor_layers or [200, 150, 100],
        eval_every=eval_every,
        device=device,
        threads=threads,
    )
    runs = run_sweep(
        setup_name,
        mode_list,
        list(range(seed, seed + worlds)),
        template,
        lake or default_lake(),
        out,
        transitions,
        gen_workers,
        max_ensemble,
        overwrite,
    )
    for run in runs:
        click.echo(str(run.path))


@main.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Folder for figures and tables.")
@friendly_errors
def report(runs, out) -> None:
    """Draw the paper's figures and the table of final values from run folders."""
    from train.report import report as run_report

    for path in run_report(list(runs), out):
        click.echo(str(path))


def _run_summary(path: Path) -> dict:
    from train.run_dir import RunDir

    run = RunDir.open(path)
    cfg = run.config
    rows = run.metrics()
    last = rows[-1] if rows else {}
    status = run.status()
    return {
        "run": str(path),
        "dataset_id": cfg.dataset_id,
        "state": status["state"],
        "message": status["message"],
        "step": last.get("step", 0),
        "steps": cfg.steps,
        "n_h": cfg.n_h,
        "seed": cfg.seed,
        "eval_loss": last.get("eval_loss"),
        "d_topo": last.get("d_topo"),
        "d_metric": last.get("d_metric"),
        "elapsed_s": last.get("elapsed_s"),
    }


@main.command("ls")
@click.option("--runs", type=click.Path(path_type=Path), default=RUNS, show_default=True)
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def ls_(runs, as_json) -> None:
    """List the runs under a folder."""
    from train.run_dir import CONFIG

    summaries = [_run_summary(p.parent) for p in sorted(Path(runs).glob(f"*/{CONFIG}"))]
    if as_json:
        for s in summaries:
            click.echo(json.dumps(s))
        return
    click.echo(f"{'run':<40} {'state':<11} {'step':>13} {'loss':>10} {'D_topo':>10} {'D_metric':>10}")
    for s in summaries:

        def fmt(v):
            return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"

        click.echo(
            f"{Path(s['run']).name:<40} {s['state']:<11} {s['step']:>6}/{s['steps']:<6} "
            f"{fmt(s['eval_loss']):>10} {fmt(s['d_topo']):>10} {fmt(s['d_metric']):>10}"
        )


@main.command()
@click.argument("run", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def info(run, as_json) -> None:
    """Describe one run: config, state, last metrics."""
    from train.run_dir import RunDir

    summary = _run_summary(run) | {"config": RunDir.open(run).config.to_dict()}
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    for key, value in summary.items():
        if key != "config":
            click.echo(f"{key:>12}: {value}")
    click.echo(f"{'config':>12}: {json.dumps(summary['config'])}")


@main.command()
@click.argument("run", type=click.Path(path_type=Path))
@view_options
@friendly_errors
def view(run, output) -> None:
    """Replay a run in rerun: h coloured by p, the affine projection, curves, predictions."""
    from train.run_dir import RunDir
    from train.view import view_run

    n = view_run(RunDir.open(run), output)
    if output.save:
        click.echo(f"{output.save}\t{n} evaluations")


if __name__ == "__main__":
    sys.exit(main())
