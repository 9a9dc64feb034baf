"""`smtrain bench` and `smtrain leaderboard` (docs/BENCHMARK.md): added to smtrain's group by
study/cli.py, since a benchmark composes generation, studies and training."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import click

from smspace.common.cli import MAX_WORKERS, default_workers, executor_option, friendly_errors, on_interrupt
from smspace.common.errors import SmspaceError

BENCH_LAKE = "data/bench-lake"  # a task fixes its datasets' sizes: each suite's live apart, in BENCH_LAKE/<suite>
BENCH_OUT = "runs/bench"


def parse_entry(spec: str):
    """NAME, or NAME:key=value,key=value (values in TOML: 0.2, 16, "text", [1, 2]; a bare word is
    text), in the entry's canonical form (bench/names.py)."""
    from smspace.bench.run import Entry

    name, _, given = spec.partition(":")
    params = {}
    for pair in _split_pairs(given, spec):
        key, eq, value = pair.partition("=")
        if not eq or not key.strip():
            raise SmspaceError(f"entry {spec!r}: parameters are NAME:key=value,key=value")
        if key.strip() in params:
            raise SmspaceError(f"entry {spec!r}: parameter {key.strip()!r} is given twice")
        try:
            params[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            params[key.strip()] = value.strip()  # a bare word: text (typed by the model's default, if any)
    return Entry.of(name, params)


def _split_pairs(given: str, spec: str) -> list[str]:
    """key=value pairs split on the commas outside brackets and quotes: `k=[1, 2],t="a,b"` is two."""
    pairs, depth, quote, start = [], 0, "", 0
    for i, c in enumerate(given):
        if quote:
            quote = "" if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
        elif c == "," and depth == 0:
            pairs.append(given[start:i])
            start = i + 1
    if quote or depth:
        raise SmspaceError(f"entry {spec!r}: an unclosed quote or bracket")
    pairs.append(given[start:])
    return [p for p in pairs if p.strip()]


@click.command()
@click.argument("suite")
@click.argument("entries", nargs=-1, required=True)
@click.option("--lake", default=None, help=f"Where the suite's datasets are generated [default: {BENCH_LAKE}/SUITE].")
@click.option("--out", default=BENCH_OUT, show_default=True, help="Folder (or fsspec URL) for the results.")
@click.option(
    "--workers", type=click.IntRange(1, MAX_WORKERS), default=None, help="Ensembles trained at once [default: cores]."
)
@click.option("--gen-workers", type=click.IntRange(1, MAX_WORKERS), default=None, help="Generator processes.")
@executor_option("ensembles train")
@click.option("--overwrite", is_flag=True, help="Replace results in --out made with another config.")
@click.option("--task", "tasks", multiple=True, help="Only this task of the suite (repeatable) [default: all].")
@click.option("--dry-run", is_flag=True, help="Print what would be generated, trained and how long; write nothing.")
@friendly_errors
def bench(suite, entries, lake, out, workers, gen_workers, executor, overwrite, tasks, dry_run) -> None:
    """Run ENTRIES (models, NAME:key=value for their parameters, or `isomap`) on every task of
    SUITE (NAME or NAME@VERSION: spatial, tiny); resumable: the same command continues."""
    from smspace.bench.run import plan_bench, run_bench
    from smspace.bench.suite import get_suite

    chosen = get_suite(suite)
    if tasks:  # a part of the suite: each result still names the version its task belongs to
        chosen = replace(chosen, tasks=tuple(chosen.task(name) for name in dict.fromkeys(tasks)))
    parsed = [parse_entry(e) for e in entries]
    workers = workers or default_workers()
    lake = lake or f"{BENCH_LAKE}/{chosen.name}"  # suites size their datasets apart: never one lake for two
    if dry_run:
        for line in plan_bench(chosen, parsed, lake, out, workers, overwrite, gen_workers):
            click.echo(line)
        return
    message = f"interrupted; the results in {out} keep their last checkpoints: the same command resumes them"
    with on_interrupt(message):
        folders = run_bench(
            chosen, parsed, lake, out, workers, gen_workers or workers, executor, overwrite,
            notify=lambda line: click.echo(line, err=True),
        )  # fmt: skip
    for folder in folders:
        click.echo(folder.url)


@click.command()
@click.argument("results", nargs=-1, required=True)
@click.option("--out", default="leaderboard", show_default=True, type=click.Path(path_type=Path))
@click.option("--html", is_flag=True, help="Also write leaderboard.html: one self-contained page to sort and filter.")
@friendly_errors
def leaderboard(results, out, html) -> None:
    """Write leaderboard.md, .json and .png in --out from the results under RESULTS (folders or
    fsspec URLs, such as runs/bench or s3://bucket/bench)."""
    from smspace.bench.leaderboard import write_leaderboard

    left_out: list[str] = []
    try:
        for path in write_leaderboard(list(results), out, left_out, html=html):
            click.echo(path)
    finally:  # what was left out is said, the table written or not
        for note in left_out:
            click.echo(f"smtrain: note: {note}", err=True)


# grouped into smgen and smtrain by smspace/cli.py
COMMANDS = (bench, leaderboard)
