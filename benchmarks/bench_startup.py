"""The command line's start-up: `smtrain --help`, `smtrain --version`, `smgen --help`, one Tab
completion, and `smtrain ls` / `smtrain info` on run folders (a 4-run study trained here first),
each run N times in a fresh process (the median is printed, as JSON).

torch takes seconds to import; the command line builds its flags without it (train/config.py) and
reads run folders without it (train/run_dir.py), so these should stay under half a second.
Usage: python benchmarks/bench_startup.py [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent

COMMANDS = {
    "smtrain --help": ([str(BIN / "smtrain"), "--help"], {}),
    "smtrain --version": ([str(BIN / "smtrain"), "--version"], {}),
    "smgen --help": ([str(BIN / "smgen"), "--help"], {}),
    "smtrain fit --<Tab>": (
        [str(BIN / "smtrain")],
        {"_SMTRAIN_COMPLETE": "bash_complete", "COMP_WORDS": "smtrain fit --", "COMP_CWORD": "2"},
    ),
}


def run_folders(tmp: Path) -> dict[str, tuple[list[str], dict[str, str]]]:
    """`ls` and `info` on a small study of this machine's making (2 worlds x MM, MME, 50 steps)."""
    runs = tmp / "runs"
    subprocess.run(
        [str(BIN / "smtrain"), "sweep", "--setup", "grid", "--modes", "MM,MME", "--worlds", "2", "--steps", "50",
         "--eval-every", "25", "--transitions", "2000", "--lake", str(tmp / "lake"), "--out", str(runs)],
        capture_output=True, check=True,
    )  # fmt: skip
    one = sorted(p for p in runs.iterdir() if p.is_dir())[0]
    return {
        "smtrain ls --runs (4 runs)": ([str(BIN / "smtrain"), "ls", "--runs", str(runs)], {}),
        "smtrain info RUN": ([str(BIN / "smtrain"), "info", str(one)], {}),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    result = {}
    with tempfile.TemporaryDirectory() as tmp:  # the run folders go when the timing is done
        commands = COMMANDS | run_folders(Path(tmp))
        for name, (cmd, env) in commands.items():
            times = []
            for _ in range(args.runs):
                started = time.perf_counter()
                subprocess.run(cmd, env={**os.environ, **env}, capture_output=True, check=True)
                times.append(time.perf_counter() - started)
            result[name] = round(statistics.median(times), 3)
    print(json.dumps({"median_s": result, "runs": args.runs}))


if __name__ == "__main__":
    main()
