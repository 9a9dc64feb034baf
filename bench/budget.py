"""Whether a task's ranking is settled at its step count (docs/BENCHMARK.md, "Budgets"): from the
scores every result carries at its earlier evaluations (bench/result.py, CurvePoint; each verified
against its own evidence), each entry's mean over worlds at every evaluation, the entries' ranking
at each, and whether the last evaluation changed it. A ranking that still moves at the last step
says the task's budget is too short to rank those entries, whatever the marks at that step say.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smspace.bench.verify import Result
from smspace.lake.transitions import MODES
from smspace.metrics.scores import SCORES
from smspace.metrics.spread import grouped
from smspace.train.pages import escape, save_figure

RANKED = tuple(name for name, score in SCORES.items() if score.better is not None)


def curves(results: list[Result], shown: dict[str, str]) -> list[dict[str, Any]]:
    """Per result with a budget, mode and ranked score: the evaluations' steps (the last included)
    and the mean over worlds at each."""
    out = []
    for r in results:
        for mode, rows in grouped(r.rows, lambda row: row.mode, MODES).items():
            if not all(row.curve for row in rows):
                continue
            steps = [point.step for point in rows[0].curve] + [rows[0].step]
            for score in RANKED:
                per_world = [[point.scores[score] for point in row.curve] + [row.scores[score]] for row in rows]
                means = [float(m) for m in np.mean(np.asarray(per_world), axis=0)]
                out.append({"task": r.task, "mode": mode, "entry": shown[r.where], "score": score,
                            "steps": steps, "means": means})  # fmt: skip
    return out


def rankings(table: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per task, mode and score whose entries share their evaluations: the entries best first at each
    step, and whether the last step left the ranking of the one before unchanged (`settled`)."""
    out = []
    for (task, mode, score), group in grouped(table, lambda c: (c["task"], c["mode"], c["score"])).items():
        steps = group[0]["steps"]
        if len(group) < 2 or any(c["steps"] != steps for c in group):
            continue  # one entry has no ranking; entries on other evaluations are not ranked together
        sign = 1.0 if SCORES[score].better == "lower" else -1.0
        order = [[c["entry"] for c in sorted(group, key=lambda c: (sign * c["means"][i], c["entry"]))]
                 for i in range(len(steps))]  # fmt: skip
        changed = [steps[i] for i in range(1, len(steps)) if order[i] != order[i - 1]]
        out.append({"task": task, "mode": mode, "score": score, "steps": steps, "order": order,
                    "settled": len(steps) > 1 and order[-1] == order[-2],
                    "last_change": changed[-1] if changed else None})  # fmt: skip
    return out


def markdown(ranked: list[dict[str, Any]]) -> list[str]:
    """The section the leaderboard's page adds: per task, mode and score, settled or not, and the
    ranking at each evaluation."""
    if not ranked:
        return []
    lines = ["## Budget: the ranking against steps", "",
             "Each entry's mean over worlds at every evaluation, ranked best first; *settled*: the last "
             "evaluation left the ranking of the one before unchanged.", "",
             "| task | mode | score | settled | ranking at each step (best first) |",
             "|---|---|---|---|---|"]  # fmt: skip
    for r in ranked:
        said = "yes" if r["settled"] else f"no (changed at step {r['last_change']})"
        steps = "; ".join(f"{step}: {' > '.join(order)}" for step, order in zip(r["steps"], r["order"], strict=True))
        lines.append("| " + " | ".join(escape(c) for c in (r["task"], r["mode"], SCORES[r["score"]].title, said, steps))
                     + " |")  # fmt: skip
    return [*lines, ""]


def figure(table: list[dict[str, Any]], path: Path, title: str) -> bool:
    """D_metric and the probe against steps, a panel per task and mode, a line per entry; False
    (and nothing written) where no result has a budget."""
    shown = [c for c in table if c["score"] in ("d_metric", "probe_r2")]
    if not shown:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = list(dict.fromkeys((c["task"], c["mode"]) for c in shown))
    fig, axes = plt.subplots(2, len(panels), figsize=(3.2 * len(panels) + 1, 6), squeeze=False)
    for j, (task, mode) in enumerate(panels):
        for i, score in enumerate(("d_metric", "probe_r2")):
            ax = axes[i][j]
            for c in shown:
                if (c["task"], c["mode"], c["score"]) == (task, mode, score):
                    ax.plot(c["steps"], c["means"], marker="o", markersize=3, label=c["entry"].replace("$", r"\$"))
            if score == "d_metric":
                ax.set_yscale("log")
            ax.set_title(f"{task} {mode}: {SCORES[score].title} {SCORES[score].arrow}", fontsize=9)
            ax.set_xlabel("step", fontsize=8)
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path, dpi=100, bbox_inches="tight")
    return True
