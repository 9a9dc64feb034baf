"""How much D_metric moved when its affine fit began to leave out the directions of h thinner than
float32 rounding (metrics/spatial.py, RANK_TOLERANCE): for each run under the folders given, D_metric
at its last evaluation with today's fit and with the former plain least squares on the raw h.
Prints JSON: per run and, per mode, the mean and largest relative change.

Studies drawn before the change (docs/REPRODUCTION.md says which) can be judged by it:
    python scripts/affine_fit_effect.py runs/grid-nh25-check
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

import smspace
from smspace.train.report import expand_runs  # run folders, given or by their study's folder


def plain_fit(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The former fit: least squares of p on [h, 1] with NumPy's default cutoff."""
    x = np.hstack([np.asarray(h, np.float64), np.ones((len(h), 1))])
    coef, *_ = np.linalg.lstsq(x, np.asarray(p, np.float64), rcond=None)
    return x @ coef


def former_d_metric(h: np.ndarray, p: np.ndarray) -> float:
    """D_metric of the former fit. D_metric sees h only through its fit ĥ, and the fit of p on an ĥ
    that is already p's projection onto a span containing it returns that ĥ: so scoring ĥ gives it."""
    return smspace.spatial_scores(plain_fit(h, p), p).d_metric


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("roots", nargs="+", help="study or run folders")
    args = parser.parse_args()
    runs, changes = [], defaultdict(list)
    for folder in expand_runs(args.roots):
        run = smspace.open_run(folder)
        rows = run.metrics()
        if not rows:
            continue
        step = rows[-1]["step"]
        h, p = run.embeddings(step)
        now, former = smspace.spatial_scores(h, p).d_metric, former_d_metric(h, p)
        mode = run.config.mode
        change = (now - former) / former if former else 0.0
        changes[mode].append(change)
        runs.append({"run": Path(folder).name, "mode": mode, "n_h": run.config.n_h, "step": step, "d_metric": now,
                     "d_metric_former_fit": former, "relative_change": change})  # fmt: skip
    modes = {
        mode: {"runs": len(c), "mean_relative_change": float(np.mean(c)), "largest": float(np.max(np.abs(c)))}
        for mode, c in sorted(changes.items())
    }
    print(json.dumps({"modes": modes, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
