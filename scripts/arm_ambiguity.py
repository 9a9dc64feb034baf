"""How ambiguous is each arm room: do camera positions far apart see images as alike as neighbours?

The paper explains the arm's high MM D_topo (and, here, its high MM D_metric) by sensory ambiguity:
in a fixed room, distant sensor positions can see similar images, and h may fold them together.
This measures that per world on a small MM dataset (the room never moves, shift 0) and sets it
beside the final metrics of the runs, so the explanation is checked rather than assumed.

Usage: .venv/bin/python scripts/arm_ambiguity.py --seeds 0-5 --runs docs/reproduction/arm/runs.csv \
           --runs docs/reproduction/arm-more/runs.csv            (prints JSON)
"""

from __future__ import annotations

import argparse
import csv
import json
import re
from pathlib import Path

import numpy as np

from smspace.datagen.generate import generate
from smspace.lake.dataset import Dataset
from smspace.metrics.ambiguity import FAR, K, spearman, view_ambiguity


def seeds_from(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def final_metrics(paths: list[Path]) -> dict[tuple[int, str], dict[str, float]]:
    """(world, mode) → final D_topo, D_metric, from runs.csv files of `smtrain report`."""
    out = {}
    for path in paths:
        with open(path) as fh:
            for row in csv.DictReader(fh):
                world = int(re.search(r"-seed(\d+)-", row["run"]).group(1))
                out[(world, row["mode"])] = {"d_topo": float(row["d_topo"]), "d_metric": float(row["d_metric"])}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-5", help="World seeds, e.g. 0-5.")
    parser.add_argument("--lake", default="data/ambiguity-lake", help="Scratch lake for the small MM datasets.")
    parser.add_argument("--transitions", type=int, default=1024)
    parser.add_argument("--runs", type=Path, action="append", default=[], help="runs.csv of a report (repeatable).")
    args = parser.parse_args()
    seeds = seeds_from(args.seeds)
    Path(args.lake).mkdir(parents=True, exist_ok=True)
    generate(args.lake, "arm", ["MM"], seeds, args.transitions, args.transitions, workers=1)
    metrics = final_metrics(args.runs)
    worlds = []
    for seed in seeds:
        tr = Dataset.open(f"arm-seed{seed}-MM", args.lake).read_all()
        row = {"world": seed, **view_ambiguity(tr.p_t, tr.s_t)}
        for mode in ("MEM", "MM"):
            for key, value in metrics.get((seed, mode), {}).items():
                row[f"{mode}_{key}"] = value
        worlds.append(row)
    result: dict[str, object] = {"k": K, "far": FAR, "transitions": args.transitions, "worlds": worlds}
    known = [w for w in worlds if "MM_d_metric" in w and "MEM_d_metric" in w]
    if len(known) >= 3:
        alike = np.array([w["lookalike_distance"] for w in known])
        for key in ("MM_d_metric", "MM_d_topo", "MEM_d_metric"):
            result[f"spearman_lookalike_distance_vs_{key}"] = spearman(alike, np.array([w[key] for w in known]))
        for key in ("d_metric", "d_topo"):
            image = np.array([w[f"image_geometry_{key}"] for w in known])
            result[f"spearman_image_geometry_vs_MM_{key}"] = spearman(image, np.array([w[f"MM_{key}"] for w in known]))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
