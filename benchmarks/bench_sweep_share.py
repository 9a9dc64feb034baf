"""Where a sweep's wall time goes, outside the training step: a profile of a whole sweep, not of
the step. A grid study (W worlds x 3 modes) is generated first, then `smtrain sweep` trains it on
one worker in a fresh process (in-process training: one worker), with timers around the step,
the batches, the evaluations and the run-folder writes. Start-up is the time from the process's
start to the sweep's first line of work.

Prints one JSON object: seconds and shares of the sweep's wall time for each part, and the share
outside the step (issue 30 asks for under 5 %). Run it alone; say what else ran beside it.
Usage: python benchmarks/bench_sweep_share.py [--worlds 10] [--steps 3000] [--compile]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def child(lake: str, out: str, worlds: int, steps: int, compile: bool, spawned_at: float) -> None:
    """The sweep, timed part by part in this process."""
    started = time.time()
    from smspace.cli import smtrain as main
    from smspace.train import engine, fit

    spent: dict[str, float] = {"step": 0.0, "batches": 0.0, "evaluation": 0.0, "run-folder writes": 0.0}

    def timed(part: str, fn):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[part] += time.perf_counter() - t

        return wrapper

    engine.EnsembleLearner.train_step = timed("step", engine.EnsembleLearner.train_step)
    engine.EnsembleLearner.evaluate = timed("evaluation", engine.EnsembleLearner.evaluate)
    engine.scores_row = timed("evaluation", engine.scores_row)
    engine._next_batch = timed("batches", engine._next_batch)
    fit.RunFolders.on_evaluation = timed("run-folder writes", fit.RunFolders.on_evaluation)
    fit.RunFolders.on_finish = timed("run-folder writes", fit.RunFolders.on_finish)
    args = ["sweep", "--setup", "grid", "--modes", "all", "--worlds", str(worlds), "--steps", str(steps),
            "--lake", lake, "--out", out, "--workers", "1"] + (["--compile"] if compile else [])  # fmt: skip
    imported = time.time()
    t0 = time.perf_counter()
    try:
        main(args, standalone_mode=False)
    except SystemExit as e:
        if e.code:
            raise
    sweep_s = time.perf_counter() - t0
    total = imported - spawned_at + sweep_s
    parts = {"start-up (process and imports)": imported - spawned_at} | spent
    parts["other (planning, run folders, compilation, loaders' start)"] = sweep_s - sum(spent.values())
    print(
        json.dumps(
            {
                "benchmark": "sweep_share",
                "runs": worlds * 3,
                "steps": steps,
                "compile": compile,
                "wall_s": round(total, 2),
                "seconds": {k: round(v, 2) for k, v in parts.items()},
                "share": {k: round(v / total, 4) for k, v in parts.items()},
                "outside_the_step_share": round(1 - spent["step"] / total, 4),
                "process_start_s": round(started - spawned_at, 2),
            }
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--compile", action="store_true")
    ap.add_argument("--child", nargs=3, metavar=("LAKE", "OUT", "SPAWNED_AT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        lake, out, spawned_at = args.child
        child(lake, out, args.worlds, args.steps, args.compile, float(spawned_at))
        return
    with tempfile.TemporaryDirectory() as tmp:
        lake, out = f"{tmp}/lake", f"{tmp}/runs"
        subprocess.run(
            [str(BIN / "smgen"), "generate", "--setup", "grid", "--mode", "all", "--worlds", str(args.worlds),
             "--lake", lake],
            check=True, capture_output=True,
        )  # fmt: skip
        cmd = [sys.executable, __file__, "--worlds", str(args.worlds), "--steps", str(args.steps)]
        cmd += ["--compile"] if args.compile else []
        done = subprocess.run([*cmd, "--child", lake, out, str(time.time())], capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "sweep failed")
        print(done.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    main()
