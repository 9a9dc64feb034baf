"""Arm rendering speed: generate an `arm` dataset with N workers and report transitions/s,
renders/s, CPU-ms per render and the projected time for a paper-sized (150000) dataset.

Prints one JSON object. Worker start-up (SAPIEN import, scene build) is included, as a user
pays it. Usage: python benchmarks/bench_arm.py [--transitions 30000] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

from smspace.datagen.generate import generate


def cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--setup", default="arm")
    ap.add_argument("--transitions", type=int, default=30_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--shard-size", type=int, default=4096)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cpu0, t0 = cpu_seconds(), time.perf_counter()
        ((manifest, _),) = generate(
            Path(tmp), args.setup, ["MEM"], [0], args.transitions, args.shard_size, workers=args.workers
        )
        wall, cpu = time.perf_counter() - t0, cpu_seconds() - cpu0
    renders = 2 * args.transitions  # s_t and s_t1; the regular sampling needs kinematics only
    print(
        json.dumps(
            {
                "benchmark": "arm_render",
                "setup": args.setup,
                "workers": args.workers,
                "transitions": args.transitions,
                "wall_seconds": round(wall, 2),
                "transitions_per_s": round(args.transitions / wall),
                "renders_per_s": round(renders / wall),
                "cpu_ms_per_render": round(1e3 * cpu / renders, 3),
                "projected_seconds_150k": round(150_000 / (args.transitions / wall)),
                "bytes_per_transition": round(manifest.total_bytes / args.transitions, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
