"""Data-lake speed: generate a paper-sized grid dataset on one core, read it back into numpy.

Prints one JSON object. Timings are best-of-N wall-clock seconds on this (shared, noisy) machine.
Usage: python benchmarks/bench_lake.py [--transitions 150000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from smspace.datagen.generate import generate
from smspace.lake.dataset import Dataset


def best_of(repeats: int, fn) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--setup", default="grid")
    ap.add_argument("--transitions", type=int, default=150_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lakes = iter(range(10_000))

        def gen() -> None:
            generate(Path(tmp) / f"lake{next(lakes)}", args.setup, ["MME"], [0], args.transitions, 32768, workers=1)

        gen_s = best_of(args.repeats, gen)
        ds = Dataset.open(Path(tmp) / "lake0" / f"{args.setup}-seed0-MME")
        read_s = best_of(args.repeats, ds.read_all)
        size = ds.manifest.total_bytes
    print(
        json.dumps(
            {
                "benchmark": "lake",
                "setup": args.setup,
                "transitions": args.transitions,
                "generate_seconds_one_core": round(gen_s, 3),
                "generate_transitions_per_s": round(args.transitions / gen_s),
                "read_seconds": round(read_s, 3),
                "read_transitions_per_s": round(args.transitions / read_s),
                "bytes_on_disk": size,
                "bytes_per_transition": round(size / args.transitions, 2),
                "cpu_count": os.cpu_count(),
            }
        )
    )


if __name__ == "__main__":
    main()
