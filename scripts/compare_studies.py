"""Two studies of the same worlds side by side, from the runs.csv files `smtrain report` writes:
per mode, each metric's mean ± std over worlds in both, the other study's mean in units of the
reference's spread, and how many worlds moved which way. Prints JSON.

Used for the bf16 grid study against the fp32 one (docs/REPRODUCTION.md, "bf16"):
    python scripts/compare_studies.py docs/reproduction/grid/runs.csv docs/reproduction/grid-bf16/runs.csv
"""

from __future__ import annotations

import argparse
import csv
import json
import re
from collections import defaultdict

import numpy as np

METRICS = ("eval_loss", "d_topo", "d_metric")


def read(path: str) -> dict[tuple[str, int], dict[str, float]]:
    """(mode, world) -> final metrics."""
    out = {}
    with open(path) as fh:
        for row in csv.DictReader(fh):
            world = int(re.search(r"-seed(\d+)-", row["run"]).group(1))
            out[(row["mode"], world)] = {k: float(row[k]) for k in METRICS}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", help="runs.csv of the reference study")
    parser.add_argument("other", help="runs.csv of the study compared with it")
    args = parser.parse_args()
    ref, other = read(args.reference), read(args.other)
    shared = sorted(ref.keys() & other.keys())
    by_mode: dict[str, list[tuple[str, int]]] = defaultdict(list)
    for key in shared:
        by_mode[key[0]].append(key)
    result: dict = {"worlds_compared": len({w for _, w in shared}), "modes": {}}
    for mode, keys in sorted(by_mode.items()):
        cell = {}
        for metric in METRICS:
            a = np.array([ref[k][metric] for k in keys])
            b = np.array([other[k][metric] for k in keys])
            cell[metric] = {
                "reference": [float(a.mean()), float(a.std())],
                "other": [float(b.mean()), float(b.std())],
                "other_mean_in_reference_stds": float((b.mean() - a.mean()) / a.std()) if a.std() > 0 else None,
                "ratio_of_means": float(b.mean() / a.mean()) if a.mean() else None,
                "worlds_higher_in_other": int((b > a).sum()),
                "worlds": len(keys),
            }
        result["modes"][mode] = cell
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
