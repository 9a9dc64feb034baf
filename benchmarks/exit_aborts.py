"""How often a short smspace command aborts at interpreter exit (issue: "terminate called without
an active exception", exit 134). Runs each command N times, two at a time, on a run folder it
trains first, and prints JSON: {command: {"runs": N, "aborts": k, "exit_codes": {...}}}.

    .venv/bin/python benchmarks/exit_aborts.py --runs 200
"""

from __future__ import annotations

import argparse
import collections
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--parallel", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        trained = subprocess.run(
            [BIN / "smtrain", "fit", "grid-seed0-MM", "--lake", ROOT / "data" / "samples", "--out", run,
             "--steps", "40", "--eval-every", "20"], capture_output=True, text=True,
        )  # fmt: skip
        if trained.returncode != 0:
            sys.exit(f"exit_aborts: training the probe run failed: {trained.stderr.strip()[-300:]}")
        commands = {
            "python -c 'smspace.open_run(R).metrics()'": [
                sys.executable,
                "-c",
                f"import smspace; smspace.open_run({str(run)!r}).metrics()",
            ],
            "smtrain ls --runs R/..": [str(BIN / "smtrain"), "ls", "--runs", str(run.parent)],
        }
        report = {}
        for name, cmd in commands.items():
            with ThreadPoolExecutor(args.parallel) as pool:
                codes = list(
                    pool.map(lambda _, cmd=cmd: subprocess.run(cmd, capture_output=True).returncode, range(args.runs))
                )
            counts = collections.Counter(codes)
            report[name] = {"runs": args.runs, "aborts": counts.get(-6, 0) + counts.get(134, 0),
                            "exit_codes": {str(k): v for k, v in sorted(counts.items())}}  # fmt: skip
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
