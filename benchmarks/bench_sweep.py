"""Wall time of one grid sweep (10 worlds × 3 modes = 30 runs) trained on one core, on every core
with `--executor local`, and on every core with `--executor ray` (a local Ray started by the sweep).

The datasets are generated once beforehand, so only training is timed; each configuration writes
its own run folders. Prints one JSON object. This takes a while (about 20 minutes on 2 cores at
10000 steps): run it alone, the machine's other load shows in the figures.
Usage: python benchmarks/bench_sweep.py [--worlds 10] [--steps 10000] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def timed_sweep(common: list[str], out: Path, extra: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(
        [str(BIN / "smtrain"), "sweep", *common, "--out", str(out), *extra],
        capture_output=True,
        text=True,
        env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"},
    )
    if proc.returncode != 0:
        raise SystemExit(f"sweep {' '.join(extra)} failed: {proc.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--transitions", type=int, default=30_000)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lake = Path(tmp) / "lake"
        gen = [str(BIN / "smgen"), "generate", "--setup", "grid", "--mode", "all", "--worlds", str(args.worlds)]
        subprocess.run(
            [*gen, "--transitions", str(args.transitions), "--lake", str(lake)], check=True, capture_output=True
        )
        common = ["--setup", "grid", "--worlds", str(args.worlds), "--transitions", str(args.transitions)]
        common += ["--steps", str(args.steps), "--eval-every", str(max(1, args.steps // 10)), "--lake", str(lake)]
        runs = 3 * args.worlds
        one = timed_sweep(common, Path(tmp) / "one", ["--workers", "1"])
        local = timed_sweep(common, Path(tmp) / "local", ["--workers", str(args.workers)])
        ray = timed_sweep(common, Path(tmp) / "ray", ["--workers", str(args.workers), "--executor", "ray"])
    print(
        json.dumps(
            {
                "benchmark": "sweep",
                "runs": runs,
                "steps": args.steps,
                "workers": args.workers,
                "one_core_s": round(one, 1),
                "local_s": round(local, 1),
                "ray_s": round(ray, 1),
                "local_speedup": round(one / local, 2),
                "ray_speedup": round(one / ray, 2),
                "one_core_ms_per_run_step": round(1e3 * one / (runs * args.steps), 3),
                "cpu_count": os.cpu_count(),
            }
        )
    )


if __name__ == "__main__":
    main()
