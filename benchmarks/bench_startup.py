"""The command line's start-up: `smtrain --help`, `smtrain --version`, `smgen --help` and one Tab
completion, each run N times in a fresh process (the median is printed, as JSON).

torch takes seconds to import; the command line builds its flags without it (train/config.py), so
these should stay well under a second. Usage: python benchmarks/bench_startup.py [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    result = {}
    for name, (cmd, env) in COMMANDS.items():
        times = []
        for _ in range(args.runs):
            started = time.perf_counter()
            subprocess.run(cmd, env={**os.environ, **env}, capture_output=True, check=True)
            times.append(time.perf_counter() - started)
        result[name] = round(statistics.median(times), 3)
    print(json.dumps({"median_s": result, "runs": args.runs}))


if __name__ == "__main__":
    main()
