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
import math
from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from smspace.bench.run import BENCH, SCORES
from smspace.bench.scores import LOWER_IS_BETTER
from smspace.bench.scores import SCORES as SCORE_NAMES
from smspace.bench.suite import get_suite
from smspace.common.errors import SmspaceError
from smspace.lake.store import Store, open_store

DEPTH = 4  # folders below a given one where results are looked for (out/suite/entry/task)
TITLES = {
    "d_topo": "D_topo (lower: better)",
    "d_metric": "D_metric (lower: better)",
    "probe_r2": "held-out probe R² of p from h (higher: better)",
    "local_dim": "local-PCA dimension of h",
}


@dataclass(frozen=True)
class Result:
    where: str
    suite: str
    version: int
    task: str
    entry: str
    wall_s: float  # over the sessions that ended
    wall_complete: bool  # False: a session was interrupted or failed, and its time is not in wall_s
    rows: list[dict[str, Any]]


def find_results(paths: list[str | Path], left_out: list[str] | None = None) -> list[Result]:
    """The results under `paths`; one begun whose first session has not ended (no scores yet) is
    left out, its folder added to `left_out`."""
    found = []
    for path in paths:
        store = open_store(str(path))
        names = [name for depth in range(DEPTH) for name in store.list("/".join(["*"] * depth + [BENCH]))]
        if not names:
            raise SmspaceError(f"{store.url} holds no benchmark result ({BENCH}) within {DEPTH} folders")
        for name in names:
            folder = store
            for part in name.split("/")[:-1]:
                folder = folder.child(part)
            if not folder.exists(SCORES):
                if left_out is not None:
                    left_out.append(folder.url)
                continue
            where = "/".join([str(path).rstrip("/"), *name.split("/")[:-1]])  # as given: a leaderboard moves
            found.append(replace(_read(folder), where=where))
    return found


def _read(folder: Store) -> Result:
    try:
        record = json.loads(folder.read_bytes(BENCH))
        rows = json.loads(folder.read_bytes(SCORES))
        suite = get_suite(f"{record['suite']}@{record['version']}")
        task = suite.task(record["task"]["name"])
        entry = record["entry"]["name"] + _params(record["entry"].get("params") or {})
        walls = [s["wall_s"] for s in record["sessions"]]
        mode_of_rows = [row["mode"] for row in rows]
    except (FileNotFoundError, KeyError, TypeError, ValueError) as e:
        raise SmspaceError(f"{folder.url} is not a readable benchmark result ({type(e).__name__}: {e})") from None
    if record["task"] != task.protocol():
        changed = sorted(k for k in task.protocol() if record["task"].get(k) != task.protocol()[k])
        raise SmspaceError(
            f"{folder.url}: task {task.name} was measured under another protocol than {suite.label} fixes "
            f"({', '.join(changed)} differ); it is not comparable"
        )
    if len(rows) != task.worlds * len(task.modes) or set(mode_of_rows) != set(task.modes):
        raise SmspaceError(f"{folder.url}: {len(rows)} scored runs, where task {task.name} has "
                           f"{task.worlds} worlds x {len(task.modes)} modes")  # fmt: skip
    wall = sum(float(w) for w in walls if w is not None)
    return Result(folder.url, suite.name, suite.version, task.name, entry, wall, None not in walls, rows)


def _params(params: dict[str, Any]) -> str:
    return "" if not params else " (" + ", ".join(f"{k}={v}" for k, v in sorted(params.items())) + ")"


def cells(results: list[Result]) -> list[dict[str, Any]]:
    """One cell per entry, task, mode and score: mean, standard deviation and count over worlds."""
    seen: dict[tuple[str, str, str], str] = {}
    for r in results:
        key = (r.suite, r.task, r.entry)
        if key in seen:
            raise SmspaceError(
                f"two results of {r.entry} on {r.suite} task {r.task} ({seen[key]} and {r.where}): "
                "they are not pooled; give one"
            )
        seen[key] = r.where
    table = []
    for r in results:
        by_mode: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for row in r.rows:
            by_mode[row["mode"]].append(row)
        for mode, rows in sorted(by_mode.items()):
            for score in SCORE_NAMES:
                values = np.array([float(row[score]) for row in rows])
                table.append({"suite": r.suite, "version": r.version, "task": r.task, "mode": mode, "entry": r.entry,
                              "score": score, "mean": float(values.mean()),
                              "std": float(values.std(ddof=1)) if len(values) > 1 else math.nan,
                              "worlds": sorted(int(row["world"]) for row in rows), "wall_s": r.wall_s})  # fmt: skip
    return table


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


def write_leaderboard(paths: list[str | Path], out: Path, left_out: list[str] | None = None) -> list[Path]:
    results = find_results(paths, left_out)
    suites = sorted({r.suite for r in results})
    if len(suites) > 1:
        raise SmspaceError(f"results of several suites ({', '.join(suites)}): one leaderboard per suite")
    table = cells(results)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "leaderboard.json", out / "leaderboard.md", out / "leaderboard.png"]
    versions = sorted({r.version for r in results})
    head = {"suite": suites[0], "versions": versions, "results": sorted(r.where for r in results)}
    written[0].write_text(json.dumps(head | {"cells": table}, indent=1) + "\n")
    written[1].write_text(markdown(table, results, head))
    figure(table, written[2], head)
    return written


def _cell(table: list[dict[str, Any]], entry: str, task: str, mode: str, score: str) -> dict[str, Any] | None:
    key = (entry, task, mode, score)
    return next((c for c in table if (c["entry"], c["task"], c["mode"], c["score"]) == key), None)


def _shown(cell: dict[str, Any] | None) -> str:
    if cell is None:
        return "—"
    spread = "" if math.isnan(cell["std"]) else f" ± {cell['std']:.3g}"
    return f"{cell['mean']:.3g}{spread}"


def markdown(table: list[dict[str, Any]], results: list[Result], head: dict[str, Any]) -> str:
    cols, rows = columns(table), entries(table)
    versions = ", ".join(f"v{v}" for v in head["versions"])
    lines = [f"# smspace-bench: {head['suite']} ({versions})", "",
             f"{len(results)} result(s); each cell: mean ± standard deviation over worlds.", "",
             _row("task", ["setup", "modes", "worlds", "transitions", "steps"]), "|---|" + "---|" * 5]  # fmt: skip
    suite = get_suite(f"{head['suite']}@{max(head['versions'])}")
    for name in dict.fromkeys(t for t, _ in cols):
        task = suite.task(name)
        lines.append(_row(name, [task.setup, ", ".join(task.modes), str(task.worlds), str(task.transitions),
                                 str(task.steps)]))  # fmt: skip
    lines.append("")
    for score in SCORE_NAMES:
        lines += [f"## {TITLES[score]}", "", _row("entry", [f"{t} {m}" for t, m in cols]), "|---|" + "---|" * len(cols)]
        lines += [_row(e, [_shown(_cell(table, e, t, m, score)) for t, m in cols]) for e in rows]
        lines.append("")
    tasks = list(dict.fromkeys(t for t, _ in cols))
    lines += ["## Wall time (s, all sessions)", "", _row("entry", tasks), "|---|" + "---|" * len(tasks)]
    walls = {(r.entry, r.task): r for r in results}
    lines += [_row(e, [_wall(walls.get((e, t))) for t in tasks]) for e in rows]
    if not all(r.wall_complete for r in results):
        lines += ["", "≥: a session of that result was interrupted or failed; its time is not counted."]
    return "\n".join(lines) + "\n"


def _row(first: str, rest: list[str]) -> str:
    return "| " + " | ".join([first, *rest]) + " |"


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
                    es.append(0.0 if math.isnan(cell["std"]) else cell["std"])
            ax.errorbar(xs, ys, yerr=es, fmt="o", capsize=3, label=entry)
        if score == "local_dim":  # what a representation of positions in the plane gives
            ax.axhline(2.0, color="grey", linestyle="--", linewidth=0.8, label="_the plane")
        ax.set_title(TITLES[score] + (" (the plane: 2, dashed)" if score == "local_dim" else ""), fontsize=10)
        ax.set_xticks(range(len(cols)), [f"{t}\n{m}" for t, m in cols], fontsize=8)
        ax.set_xlim(-0.6, len(cols) - 0.4)
        if LOWER_IS_BETTER[score] and all(c["mean"] > 0 for c in table if c["score"] == score):
            ax.set_yscale("log")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8, ncol=min(len(rows), 5), loc="upper center", bbox_to_anchor=(0.5, 1.45))
    fig.suptitle(f"smspace-bench {head['suite']} ({', '.join(f'v{v}' for v in head['versions'])})", y=1.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
