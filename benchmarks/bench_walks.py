"""Drawing walks against drawing independent transitions, in one process: transitions/s of
datagen/walks.py draw_walks and of the setups' draw_transitions, for the grid and the arm (drawing
and sensing only: no shard is written). A walk senses each time point once, so the arm, whose cost
is rendering, should draw walks near twice as fast.

Prints one JSON object. CPU time is reported beside wall time: on a busy machine compare those.
Usage: python benchmarks/bench_walks.py [--transitions 4000] [--length 100]
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

from smspace.datagen.setups import get_setup
from smspace.datagen.setups.base import draw_transitions
from smspace.datagen.walks import draw_walks

STEPS = {"grid": 1, "arm": 0.05}


def cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def timed(fn) -> dict[str, float]:
    cpu0, t0 = cpu_seconds(), time.perf_counter()
    n = len(fn())
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - cpu0
    return {"transitions_per_s": round(n / wall), "transitions_per_cpu_s": round(n / cpu)}


def measure(world, step: float, episodes: int, length: int) -> dict[str, dict[str, float]]:
    n = episodes * length
    return {
        "transitions": timed(lambda: draw_transitions(world, "MME", np.random.default_rng(0), n)),
        "walks": timed(lambda: draw_walks(world, "MME", np.random.default_rng(0), episodes, length, step).transitions),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--transitions", type=int, default=4000)
    ap.add_argument("--length", type=int, default=100, help="steps per episode")
    args = ap.parse_args()
    episodes = max(1, args.transitions // args.length)
    out = {"benchmark": "walks", "transitions": episodes * args.length, "episode_length": args.length}
    for setup, step in STEPS.items():
        world = get_setup(setup).build(0)
        world.sense(*[np.zeros((1, 2))] * 2)  # start-up (a scene build) outside the timing
        out[setup] = measure(world, step, episodes, args.length)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
