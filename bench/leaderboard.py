"""`smtrain leaderboard`: every result found under the given folders (local or any fsspec URL),
checked against the suite version it names, as one table per score (entries x task and mode, each
cell the mean and standard deviation over worlds) in leaderboard.md, leaderboard.json and
leaderboard.png, with the wall time each entry took per task.

A result whose task differs from what its suite version fixes (edited by hand, or measured by an
smspace whose suite differed) is refused, naming its folder; two results of one entry on one task
are never pooled.
"""

from __future__ import annotations

import json
import os
import stat
from collections import defaultdict
from pathlib import Path
from typing import Any

from smspace.bench import budget, differences, page
from smspace.bench.run import BENCH
from smspace.bench.suite import get_suite
from smspace.bench.verify import NotScored, Result, verify
from smspace.common.errors import SmspaceError
from smspace.lake import scan
from smspace.lake.store import Store, canonical, open_store
from smspace.lake.transitions import MODES
from smspace.metrics.scores import SCORES
from smspace.metrics.spread import Spread, as_cell, grouped
from smspace.train.pages import escape, record_files, recorded_files, refuse_inside, save_figure, write_atomically

SCORE_NAMES = tuple(SCORES)
RECORD = ".smspace-leaderboard.json"  # the pages the last leaderboard wrote here


def find_results(paths: list[str | Path], left_out: list[str] | None = None) -> list[Result]:
    """The results under `paths`, each verified (bench/verify.py); one whose sessions have written
    no scores yet is left out, said in `left_out`. A folder given twice (or inside another given)
    is read once."""
    found, seen = [], set()
    for path in paths:
        store = open_store(str(path))
        _refuse_irregular(store, scan.patterns(BENCH))
        names = scan.folders_holding(store, BENCH)
        if not names:
            raise SmspaceError(f"{store.url} holds no benchmark result ({BENCH}) within {scan.MAX_DEPTH} folders")
        for name in names:
            folder = scan.descend(store, name)
            if canonical(folder) in seen:
                continue
            seen.add(canonical(folder))
            where = "/".join([str(path).rstrip("/"), *filter(None, name.split("/"))])  # as given: a leaderboard moves
            try:
                found.append(verify(folder, where))
            except NotScored as e:
                if left_out is not None:
                    left_out.append(str(e))
    return found


def _refuse_irregular(store: Store, patterns: list[str]) -> None:
    """A bench.json that is a link, FIFO or folder is named, never skipped in silence (listing
    sees only plain files) nor opened (a FIFO would block)."""
    local = store.local_path
    if local is None:
        return
    for pattern in patterns:
        for path in local.glob(pattern):
            if not stat.S_ISREG(os.lstat(path).st_mode):
                raise SmspaceError(f"{path}: not a regular file (a link, folder or special file); results are plain")


def cells(results: list[Result]) -> list[dict[str, Any]]:
    """One cell per entry, task, mode and score: mean, standard deviation (None for one world) and
    count over worlds. An entry whose results were made by several codes gets a row per code."""
    seen: dict[tuple[str, str, str], str] = {}
    for r in results:
        key = (r.suite, r.task, r.key)
        if key in seen:
            raise SmspaceError(
                f"two results of {r.entry} on {r.suite} task {r.task} ({seen[key]} and {r.where}): "
                "they are not pooled; give one"
            )
        seen[key] = r.where
    shown = row_names(results)
    table = []
    for r in results:
        for mode, rows in grouped(r.rows, lambda row: row.mode, MODES).items():
            rows = sorted(rows, key=lambda row: row.world)
            for score in SCORE_NAMES:
                values = [row.scores[score] for row in rows]
                spread = Spread.of(values)
                table.append({"suite": r.suite, "version": r.version, "task": r.task, "mode": mode,
                              "entry": shown[r.where], "code": r.code, "score": score, "mean": spread.mean,
                              "std": spread.std, "worlds": [row.world for row in rows], "values": values,
                              "wall_s": r.wall_s})  # fmt: skip
    differences.mark(table, {shown[r.where] for r in results if r.entry == differences.FLOOR})
    return table


def row_names(results: list[Result]) -> dict[str, str]:
    """A row is one entry and one code: where an entry's results were made by several codes, each
    row names its code."""
    codes: dict[str, set[str]] = defaultdict(set)
    for r in results:
        codes[r.key].add(r.code)
    return {r.where: r.entry if len(codes[r.key]) == 1 else f"{r.entry} [code {r.code[:12]}]" for r in results}


def columns(table: list[dict[str, Any]]) -> list[tuple[str, str]]:
    """(task, mode) in the suite's order of tasks and each task's order of modes: a suite's later
    versions only add tasks, so its latest version orders them all."""
    if not table:
        return []
    suite = get_suite(f"{table[0]['suite']}@{max(c['version'] for c in table)}")
    order = [(task.name, mode) for task in suite.tasks for mode in task.modes]
    return sorted({(c["task"], c["mode"]) for c in table}, key=order.index)


def entries(table: list[dict[str, Any]]) -> list[str]:
    return sorted({c["entry"] for c in table})


def write_leaderboard(
    paths: list[str | Path], out: Path, left_out: list[str] | None = None, html: bool = False
) -> list[Path]:
    """leaderboard.json, .md and .png in `out` (and the page to browse, leaderboard.html, with
    `html`); results of several suites: one leaderboard per
    suite, in out/<suite>/."""
    results = find_results(paths, left_out)
    if not results:
        said = f" ({len(left_out)} left out, said above)" if left_out else ""
        raise SmspaceError(f"no result to show under {', '.join(map(str, paths))}{said}")
    if out.exists() and not out.is_dir():
        raise SmspaceError(f"--out {out} is a file, not a folder")
    refuse_inside(out, [p for p in paths if open_store(str(p)).local_path is not None], verb="reads")
    earlier = recorded_files(out, RECORD)
    suites = sorted({r.suite for r in results})
    written = []
    for suite in suites:
        mine = [r for r in results if r.suite == suite]
        written += _write_one(mine, out if len(suites) == 1 else out / suite, html)
    record_files(out, RECORD, earlier, written)  # one suite's pages of an earlier run: removed, not left stale
    return written


def _write_one(results: list[Result], out: Path, html: bool = False) -> list[Path]:
    table = cells(results)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SmspaceError(f"cannot create folder {out}: {e.strerror or e}") from None
    versions = sorted({r.version for r in results})
    head = {"suite": results[0].suite, "versions": versions, "results": sorted(r.where for r in results),
            "differences": differences.PROTOCOL}  # fmt: skip
    paths = [out / "leaderboard.json", out / "leaderboard.md", out / "leaderboard.png"]
    curves = budget.curves(results, row_names(results))
    ranked = budget.rankings(curves)
    budgets = {"budgets": {"curves": curves, "rankings": ranked}} if curves else {}
    write_atomically(
        paths[0], (json.dumps(head | {"cells": table} | budgets, indent=1, allow_nan=False) + "\n").encode()
    )
    write_atomically(paths[1], (markdown(table, results, head) + "\n".join(budget.markdown(ranked))).encode())
    figure(table, paths[2], head)
    budget_png = out / "budget.png"
    if budget.figure(curves, budget_png, f"smspace-bench {head['suite']}: scores against steps"):
        paths.append(budget_png)
    if html:
        paths.append(out / "leaderboard.html")
        drawn = budget_png.read_bytes() if curves else None
        text = page.page(table, results, row_names(results), head, paths[2].read_bytes(), out, ranked, drawn)
        write_atomically(paths[-1], text.encode())
    return paths


def _cell(table: list[dict[str, Any]], entry: str, task: str, mode: str, score: str) -> dict[str, Any] | None:
    key = (entry, task, mode, score)
    return next((c for c in table if (c["entry"], c["task"], c["mode"], c["score"]) == key), None)


def _shown(cell: dict[str, Any] | None) -> str:
    if cell is None:
        return "—"
    parts = [as_cell(cell["mean"], cell["std"]), differences.interval_text(cell), differences.marks(cell)]
    return " ".join(part for part in parts if part)


def markdown(table: list[dict[str, Any]], results: list[Result], head: dict[str, Any]) -> str:
    cols, rows = columns(table), entries(table)
    versions = ", ".join(f"v{v}" for v in head["versions"])
    lines = [f"# smspace-bench: {head['suite']} ({versions})", "",
             f"{len(results)} result(s); each cell: mean ± standard deviation over worlds [its 95 % "
             "bootstrap interval]; best: the best mean of its column; floor: the random encoder's; ≈best, "
             "≈floor: not told apart from the best, or from the floor, by a paired t-test over the shared "
             "worlds, Holm-corrected over the column's entries (docs/BENCHMARK.md).", "",
             _row("task", ["setup", "modes", "worlds", "transitions", "steps"]), "|---|" + "---|" * 5]  # fmt: skip
    suite = get_suite(f"{head['suite']}@{max(head['versions'])}")
    for name in dict.fromkeys(t for t, _ in cols):
        task = suite.task(name)
        lines.append(_row(name, [task.setup, ", ".join(task.modes), str(task.worlds), str(task.transitions),
                                 str(task.steps)]))  # fmt: skip
    lines.append("")
    for score in SCORE_NAMES:
        lines += [
            f"## {SCORES[score].heading}",
            "",
            _row("entry", [f"{t} {m}" for t, m in cols]),
            "|---|" + "---|" * len(cols),
        ]
        lines += [_row(e, [_shown(_cell(table, e, t, m, score)) for t, m in cols]) for e in rows]
        lines.append("")
    tasks = list(dict.fromkeys(t for t, _ in cols))
    lines += ["## Wall time (s, all sessions)", "", _row("entry", tasks), "|---|" + "---|" * len(tasks)]
    shown = row_names(results)
    walls = {(shown[r.where], r.task): r for r in results}
    lines += [_row(e, [_wall(walls.get((e, t))) for t in tasks]) for e in rows]
    if not all(r.wall_complete for r in results):
        lines += ["", "≥: a session of that result was killed before it could record its time; it is not counted."]
    return "\n".join(lines) + "\n"


def _row(first: str, rest: list[str]) -> str:
    return "| " + " | ".join(escape(c) for c in [first, *rest]) + " |"


def _wall(result: Result | None) -> str:
    if result is None:
        return "—"
    return ("" if result.wall_complete else "≥ ") + f"{result.wall_s:.0f}"


def figure(table: list[dict[str, Any]], path: Path, head: dict[str, Any]) -> None:
    """One panel per score: each entry's mean over worlds with its standard deviation, per task and mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols, rows = columns(table), entries(table)
    fig, axes = plt.subplots(len(SCORE_NAMES), 1, figsize=(max(6.0, 1.1 * len(cols) + 3), 2.6 * len(SCORE_NAMES)))
    width = 0.8 / max(1, len(rows))
    for ax, score in zip(axes, SCORE_NAMES, strict=True):
        for i, entry in enumerate(rows):
            xs, ys, es = [], [], []
            for j, (task, mode) in enumerate(cols):
                cell = _cell(table, entry, task, mode, score)
                if cell is not None:
                    xs.append(j - 0.4 + width * (i + 0.5))
                    ys.append(cell["mean"])
                    es.append(0.0 if cell["std"] is None else cell["std"])
            ax.errorbar(xs, ys, yerr=es, fmt="o", capsize=3, label=entry.replace("$", r"\$"))
        if score == "local_dim":  # what a representation of positions in the plane gives
            ax.axhline(2.0, color="grey", linestyle="--", linewidth=0.8, label="_the plane")
        ax.set_title(SCORES[score].heading + (" (the plane: 2, dashed)" if score == "local_dim" else ""), fontsize=10)
        ax.set_xticks(range(len(cols)), [f"{t}\n{m}" for t, m in cols], fontsize=8)
        ax.set_xlim(-0.6, len(cols) - 0.4)
        if SCORES[score].better == "lower" and all(c["mean"] > 0 for c in table if c["score"] == score):
            ax.set_yscale("log")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8, ncol=min(len(rows), 5), loc="upper center", bbox_to_anchor=(0.5, 1.45))
    fig.suptitle(f"smspace-bench {head['suite']} ({', '.join(f'v{v}' for v in head['versions'])})", y=1.0)
    fig.tight_layout()
    save_figure(fig, path, dpi=110, bbox_inches="tight")
