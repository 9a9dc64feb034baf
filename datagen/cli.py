"""smgen: generate, list, describe and validate datasets of the smspace data lake."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from smspace.common.cli import (
    LAKE_OPTION,
    default_workers,
    display_name,
    echo_listing,
    executor_option,
    friendly_errors,
    on_interrupt,
)
from smspace.common.completion import complete_datasets
from smspace.common.errors import SmspaceError
from smspace.common.rerun_output import view_options
from smspace.datagen.options import (
    check_seed_range,
    exploration_options,
    first_seed_option,
    generator_workers_option,
    modes_option,
    setup_option,
    transitions_option,
    worlds_option,
)
from smspace.lake.exploration import Exploration
from smspace.lake.manifest import dataset_id


@click.command()
@setup_option(required=True)
@modes_option("--mode", "mode", required=True)
@transitions_option()
@worlds_option(default=1)
@first_seed_option("seed")
@LAKE_OPTION
@generator_workers_option("--workers", "workers")
@click.option("--shard-size", type=int, default=None, help="Transitions per shard [grid 32768, arm 8192].")
@click.option("--overwrite", is_flag=True, help="Replace a dataset generated with another config.")
@exploration_options
@executor_option("the parts are drawn")
@click.option("--gpus-per-task", type=click.FloatRange(0, 64), default=0.0, help="Ray: GPUs per part (SAPIEN on CUDA).")
@click.option(
    "--rank", type=click.IntRange(min=0), default=0, help="This task's rank in a job array (with --world-size)."
)
@click.option(
    "--world-size",
    type=click.IntRange(1, 1 << 20),
    default=1,
    help="Tasks in the job array: write only shards i with i % W == RANK, commit later with `smgen finalize`.",
)
@friendly_errors
def generate(
    setup_name,
    mode,
    transitions,
    worlds,
    seed,
    lake,
    workers,
    shard_size,
    overwrite,
    exploration,
    walk_length,
    walk_step,
    executor,
    gpus_per_task,
    rank,
    world_size,
) -> None:
    """Generate datasets (resumable: re-running completes what is missing)."""
    from smspace.datagen.executors import ExecutorOptions
    from smspace.datagen.generate import Share, default_sizes
    from smspace.datagen.generate import generate as run
    from smspace.datagen.setups import get_setup, parse_modes
    from smspace.lake.dataset import lake_store

    setup = get_setup(setup_name)
    check_seed_range(seed, worlds)
    modes = parse_modes(mode)
    walk = Exploration()
    if exploration == "walk":
        walk = Exploration("walk", walk_length, setup.default_walk_step if walk_step is None else walk_step)
    n, shard_size = default_sizes(setup.name, walk, transitions, shard_size)
    store = lake_store(lake)
    share = Share(rank, world_size)
    options = ExecutorOptions(workers=workers or default_workers(), gpus_per_task=gpus_per_task)
    seeds = range(seed, seed + worlds)
    with on_interrupt("interrupted; the parts already stored are kept: the same command completes the datasets"):
        results = run(
            store,
            setup.name,
            modes,
            seeds,
            n,
            shard_size,
            overwrite=overwrite,
            executor=executor,
            share=share,
            options=options,
            notify=lambda line: click.echo(line, err=True),
            exploration=walk,
        )
    if not share.whole:
        ids = " ".join(dataset_id(setup.name, s, m) + walk.suffix for s in seeds for m in modes)
        click.echo(
            f"rank {rank} of {world_size}: parts written; once every rank is done: smgen finalize {ids}", err=True
        )
        return
    _echo_committed(store, results)


def _echo_committed(store, results) -> None:
    """One line per dataset: id, where it is, and whether this command committed it."""
    for manifest, written in results:
        click.echo(f"{manifest.dataset_id}\t{store.child(manifest.dataset_id)}\t{'written' if written else 'exists'}")


@click.command()
@click.argument("datasets", nargs=-1, required=True, shell_complete=complete_datasets)
@LAKE_OPTION
@friendly_errors
def finalize(datasets, lake) -> None:
    """Commit datasets written by the ranks of a job array, once every part is present and valid."""
    from smspace.datagen.generate import finalize as run
    from smspace.lake.dataset import lake_store, resolve_dataset

    store = lake_store(lake)
    _echo_committed(store, run(store, [resolve_dataset(ref, store) for ref in datasets]))


@click.command("ls")
@LAKE_OPTION
@click.option("--json", "as_json", is_flag=True, help="One JSON object per dataset.")
@friendly_errors
def ls_(lake, as_json) -> None:
    """List the datasets of a lake (from its catalog)."""
    from smspace.lake.catalog import manifest_versions, read_catalog
    from smspace.lake.dataset import lake_store

    store = lake_store(lake)
    if store.is_file():
        raise SmspaceError(f"lake path {store} is a file, not a folder")
    if not store.is_folder():  # a mistyped name must not look like an empty lake
        raise SmspaceError(f"no lake at {store} (nothing was generated there; --lake or $SMSPACE_LAKE names it)")
    versions = manifest_versions(store)  # one listing of the lake, for the catalog and what it leaves out
    rows = read_catalog(store, versions).to_pylist()
    left_out = sorted(set(versions) - {r["id"] for r in rows})
    echo_listing(
        rows,
        as_json,
        f"{'id':<28} {'setup':<6} {'mode':<4} {'seed':>5} {'transitions':>11} {'MB':>8}",
        lambda r: (
            f"{r['id']:<28} {r['setup']:<6} {r['mode']:<4} {r['world_seed']:>5} {r['transitions']:>11} "
            f"{r['bytes'] / 1e6:>8.2f}"
        ),
    )
    if left_out:  # a dataset whose manifest does not read is not listed, but never silently
        shown = ", ".join(left_out[:5]) + (", …" if len(left_out) > 5 else "")
        click.echo(
            f"smgen: note: {len(left_out)} dataset folder(s) left out, their manifest does not read: {shown} "
            "(`smgen validate ID` says why)",
            err=True,
        )


@click.command()
@click.argument("dataset", shell_complete=complete_datasets)
@LAKE_OPTION
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def info(dataset, lake, as_json) -> None:
    """Describe one dataset (a folder or an id in the lake)."""
    from smspace.lake.dataset import Dataset

    ds = Dataset.open(dataset, lake)
    summary = ds.manifest.summary() | {"path": ds.url}
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    for key, value in summary.items():
        click.echo(f"{key:>22}: {value}")


@click.command()
@click.argument("datasets", nargs=-1, required=True, shell_complete=complete_datasets)
@LAKE_OPTION
@friendly_errors
def validate(datasets, lake) -> None:
    """Check CRCs, counts, sha256, schema, values and the mode invariant; exit 1 on any problem."""
    from smspace.lake.dataset import resolve_dataset
    from smspace.lake.validate import validate_dataset

    bad = False
    for ref in datasets:
        folder = resolve_dataset(ref, lake)
        problems = validate_dataset(folder)
        for p in problems:
            click.echo(p)
        if problems:
            bad = True
        else:
            click.echo(f"{display_name(folder.name)}: ok")
    sys.exit(1 if bad else 0)


@click.command()
@click.argument("dataset", required=False, shell_complete=complete_datasets)
@setup_option(help="Preview a world without a dataset (with --seed).")
@first_seed_option("seed", help="The world to preview (with --setup).")
@LAKE_OPTION
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Folder for the PNGs.")
@click.option("--frames", "n_frames", type=click.IntRange(min=1, max=256), default=64, show_default=True)
@friendly_errors
def preview(dataset, setup_name, seed, lake, out, n_frames) -> None:
    """Write PNGs of a world: the room from above (arm) or the sensory table (grid), and sensor frames."""
    from smspace.datagen.preview import preview_dataset, preview_world
    from smspace.lake.dataset import Dataset

    if (dataset is None) == (setup_name is None):
        raise SmspaceError("give either DATASET or --setup (with --seed)")
    if dataset is not None:
        written = preview_dataset(Dataset.open(dataset, lake), out, n_frames)
    else:
        written = preview_world(setup_name, seed, out, n_frames)
    for path in written:
        click.echo(str(path))


@click.command()
@click.argument("dataset", shell_complete=complete_datasets)
@LAKE_OPTION
@click.option("--limit", type=click.IntRange(min=1), default=None, help="Only the first N transitions.")
@view_options
@friendly_errors
def view(dataset, lake, limit, output) -> None:
    """Replay a dataset in rerun: frames, motors, egocentric positions, shift, room map, metadata."""
    from smspace.datagen.view import view_dataset
    from smspace.lake.dataset import Dataset

    ds = Dataset.open(dataset, lake)
    n = view_dataset(ds, limit, output)
    if output.save:
        click.echo(f"{output.save}\t{n} transitions")


@click.command()
@click.argument("dataset", shell_complete=complete_datasets)
@LAKE_OPTION
@click.option("--format", "fmt", type=click.Choice(["foxglove", "parquet", "hf", "minari"]), required=True)
@click.option(
    "--out", type=click.Path(path_type=Path), required=True, help="The file (hf, minari: the folder) to write."
)
@click.option("--limit", type=click.IntRange(min=1), default=None, help="Only the first N transitions.")
@click.option("--overwrite", is_flag=True, help="Replace --out if it exists.")
@friendly_errors
def export(dataset, lake, fmt, out, limit, overwrite) -> None:
    """Export a dataset: per-transition MCAP with Foxglove schemas, Parquet, a Hugging Face
    `datasets` folder with a dataset card, or a Minari dataset of episodes."""
    from smspace.datagen.export import export as run
    from smspace.lake.dataset import Dataset

    n = run(Dataset.open(dataset, lake), fmt, out, limit, overwrite)
    click.echo(f"{out}\t{n} transitions")


# grouped into smgen and smtrain by smspace/cli.py
COMMANDS = (generate, finalize, ls_, info, validate, preview, view, export)
