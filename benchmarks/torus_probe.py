"""The probe of position modulo the period (docs/BENCHMARK.md, "The floors"): for every verified
result of a periodic world, the held-out probe R² of p from h (the plane) beside that of p modulo
the world's period (the torus, metrics/probe.py), per entry and mode, mean ± std over worlds.
Where a view repeats every period, a representation of the torus predicts as well as one of the
plane: this tells which one an entry learned, and whether the floor (random encoder) has either.

    python benchmarks/torus_probe.py runs/bench/spatial-v2 [--period 1.0]

The period is the world's own (its `period`), or --period for a world that does not declare one
(the grid torus: 10 cells). Prints JSON; reads only results the leaderboard would show.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict

import click
import numpy as np

from smspace.bench import evidence
from smspace.bench.leaderboard import find_results
from smspace.bench.suite import get_suite
from smspace.datagen.parts import world_for
from smspace.lake.store import open_store
from smspace.metrics.probe import probe_r2, torus_probe_r2


def period_of(setup: str, world: int, given: float | None) -> float | None:
    declared = getattr(world_for(setup, world), "period", None)
    return float(declared) if isinstance(declared, int | float) and math.isfinite(declared) else given


@click.command()
@click.argument("results", nargs=-1, required=True)
@click.option("--period", type=float, default=None, help="For worlds that declare no period (metres or cells).")
def main(results: tuple[str, ...], period: float | None) -> None:
    cells: dict[tuple[str, str, str, str], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for result in find_results(list(results)):
        task = get_suite(f"{result.suite}@{result.version}").task(result.task)
        store = open_store(result.where)
        for row in result.rows:
            world_period = period_of(task.setup, row.world, period)
            if world_period is None:
                continue
            p = evidence.positions(task.setup, row.world)
            h = evidence.load(store, row.h, row.h_sha256, (len(p), task.n_h))
            cell = cells[(result.task, row.mode, result.entry, f"{world_period:g}")]
            cell["plane"].append(probe_r2(h, p, seed=row.world))
            cell["torus"].append(torus_probe_r2(h, p, world_period, seed=row.world))
    stats = (("mean", np.mean), ("std", np.std))
    rows = [
        {"task": task, "mode": mode, "entry": entry, "period": float(per), "worlds": len(v["plane"])}
        | {f"{k}_{stat}": float(f(v[k])) for k in ("plane", "torus") for stat, f in stats}
        for (task, mode, entry, per), v in sorted(cells.items())
    ]
    print(json.dumps({"probe": "held-out affine, 5 folds from the world's seed", "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
