"""Which of a leaderboard's differences are real (docs/BENCHMARK.md, "Which differences are real").
Every cell gets a 95 % bootstrap interval of its mean over worlds; then, per suite, task, mode and
score, every entry is compared with the best (for a score with a direction) and with the floor
(the random encoder: what a random map of m already shows), by a paired test over the worlds both
were scored on, Holm-corrected over the entries of that group (metrics/significance.py). A cell
records its p-values and the verdicts, so the marks a page shows follow from what is stored."""

from __future__ import annotations

from typing import Any

from smspace.metrics.scores import SCORES
from smspace.metrics.significance import ALPHA, LEVEL, RESAMPLES, bootstrap_interval, holm, paired_p, seed_of
from smspace.metrics.spread import grouped

FLOOR = "random-encoder"  # bench/entries.py: the paper's network with its encoder left at its random weights
BOOTSTRAP_SEED = 0  # recorded in leaderboard.json; each cell draws from seed_of(it, the cell's names)

PROTOCOL = {
    "interval": f"percentile bootstrap of the mean over worlds, {RESAMPLES} resamples, level {LEVEL}",
    "bootstrap_seed": BOOTSTRAP_SEED,
    "test": "paired t-test over the worlds both entries were scored on, two-sided",
    "correction": f"Holm over the entries of one task, mode and score, family-wise alpha {ALPHA}",
    "floor": FLOOR,
}


def interval(cell: dict[str, Any]) -> list[float] | None:
    seed = seed_of(BOOTSTRAP_SEED, cell["suite"], cell["task"], cell["mode"], cell["score"], cell["entry"])
    found = bootstrap_interval(cell["values"], seed)
    return None if found is None else list(found)


def mark(table: list[dict[str, Any]], floor_rows: set[str]) -> None:
    """Each cell's "ci", and where its group has a best or a floor, "vs_best"/"vs_floor": the
    other cell it was compared with, the p-value, and whether the difference is real after Holm
    (None where fewer than two worlds are shared: nothing can be told)."""
    for cell in table:
        cell["ci"] = interval(cell)
    groups = grouped(table, lambda c: (c["suite"], c["task"], c["mode"], c["score"]))
    for (_, _, _, score), group in groups.items():
        better = SCORES[score].better
        best = None
        if better is not None and len(group) > 1:
            best = (min if better == "lower" else max)(group, key=lambda c: (c["mean"], c["entry"]))
        floors = [c for c in group if c["entry"] in floor_rows]
        for cell in group:
            cell["is_best"], cell["is_floor"] = cell is best, cell["entry"] in floor_rows
        for name, reference in (("vs_best", best), ("vs_floor", floors[0] if len(floors) == 1 else None)):
            for cell in group:
                cell[name] = None
            if reference is None:
                continue
            others = [c for c in group if c is not reference]
            p = {c["entry"]: _paired(c, reference) for c in others}
            real = holm({entry: value for entry, value in p.items() if value is not None})
            for c in others:
                c[name] = {"entry": reference["entry"], "p": p[c["entry"]], "real": real.get(c["entry"])}


def _paired(cell: dict[str, Any], reference: dict[str, Any]) -> float | None:
    mine = dict(zip(cell["worlds"], cell["values"], strict=True))
    theirs = dict(zip(reference["worlds"], reference["values"], strict=True))
    shared = sorted(set(mine) & set(theirs))
    return paired_p([mine[w] for w in shared], [theirs[w] for w in shared])


def interval_text(cell: dict[str, Any]) -> str | None:
    """The cell's interval as every page shows it ("[0.12, 0.15]"); None without one."""
    return None if cell.get("ci") is None else f"[{cell['ci'][0]:.3g}, {cell['ci'][1]:.3g}]"


def marks(cell: dict[str, Any]) -> str:
    """What a page shows beside a cell's value: "best", "floor"; "≈best", not told apart from the best;
    "≈floor", not told apart from the floor (a verdict of None, too few shared worlds, is not a
    real difference either); nothing beside a real difference."""
    shown = [what for what in ("best", "floor") if cell.get(f"is_{what}")]
    for name, said in (("vs_best", "≈best"), ("vs_floor", "≈floor")):
        verdict = cell.get(name)
        if verdict is not None and verdict["real"] is not True:
            shown.append(said)
    return " ".join(shown)
