"""What the peers' scripts share: their arguments, the exported dataset, and the line they print."""

from __future__ import annotations

import argparse
import json

import numpy as np

ENCODER, PREDICTOR = (150, 100, 50), (200, 150, 100)  # the paper's grid network


def arguments(ensemble: bool) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", help="the .npz run.py exported: m_t, s_t, m_t1, s_t1, normalised")
    if ensemble:
        ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--warmup", type=int, default=1000)
    ap.add_argument("--nh", type=int, default=3)
    ap.add_argument("--batch", type=int, default=100)
    return ap.parse_args()


def columns(path: str) -> list[np.ndarray]:
    data = np.load(path)
    return [data[k] for k in ("m_t", "s_t", "m_t1", "s_t1")]


def report(name: str, runs: int, steady_s: float, steady_steps: int, warmup_s: float, **versions: str) -> None:
    per_run_step_ms = steady_s / steady_steps / runs * 1e3
    line = {"contender": name, "runs": runs, "ms_per_run_step": round(per_run_step_ms, 4)}
    print(json.dumps(line | {"warmup_s": round(warmup_s, 2)} | versions))
