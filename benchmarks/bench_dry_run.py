"""The dry run against the real run: for studies of different shapes (one or two workers, a grid,
a plugin setup and network, the arm's rendering, a resume that extends), the time
`smtrain sweep STUDY --dry-run` says, then the wall time of `smtrain sweep STUDY` itself, as one
JSON line per study and a summary. Aim: every ratio within 0.7..1.3 on a quiet machine.
Usage: python benchmarks/bench_dry_run.py [--only NAME ...] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent

BASE = """
[study]
setup = "{setup}"
modes = {modes}
worlds = {worlds}
seed = 11
transitions = {transitions}
[train]
steps = {steps}
eval_every = {eval_every}
{train}
[run]
workers = {workers}
{grid}
"""

STUDIES = {  # name: the study's fields; "extends" runs the named study first, then this one over it
    "grid-2x2-w2": dict(setup="grid", modes='["MM", "MME"]', worlds=2, transitions=20000, steps=2000,
                        eval_every=500, train="", workers=2, grid=""),
    "grid-2x2-w1": dict(setup="grid", modes='["MM", "MME"]', worlds=2, transitions=20000, steps=2000,
                        eval_every=500, train="", workers=1, grid=""),
    "grid-nh-x-mode-w2": dict(setup="grid", modes='["MM", "MME"]', worlds=1, transitions=20000, steps=1500,
                              eval_every=300, train="", workers=2, grid="[grid]\nn_h = [2, 3, 4]"),
    "plugin-grid-w2": dict(setup="line", modes='["MM", "MME"]', worlds=2, transitions=10000, steps=1500,
                           eval_every=500, train="batch_size = 50", workers=2,
                           grid='[grid]\nmodel = ["sensorimotor", "shallow"]'),
    "arm-1x1-w1": dict(setup="arm", modes='["MEM"]', worlds=1, transitions=1000, steps=1000,
                       eval_every=500, train="", workers=1, grid=""),
    "grid-2x2-w2-extended": dict(setup="grid", modes='["MM", "MME"]', worlds=2, transitions=20000, steps=4000,
                                 eval_every=500, train="", workers=2, grid="", extends="grid-2x2-w2"),
}  # fmt: skip


def seconds(text: str) -> float:
    h, m, s = (int(x) for x in re.search(r"^time: about (\d+):(\d\d):(\d\d)", text, flags=re.M).groups())
    return 3600 * h + 60 * m + s


def sweep(study: Path, lake: Path, out: Path, *extra: str) -> tuple[str, float]:
    started = time.perf_counter()
    done = subprocess.run([str(BIN / "smtrain"), "sweep", str(study), "--lake", str(lake), "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=3600)  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"{study.name}: {done.stderr.strip().splitlines()[-1]}")
    return done.stdout, time.perf_counter() - started


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", nargs="*", default=list(STUDIES))
    ap.add_argument("--work", type=Path, default=None)
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-dry-run-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.only:
        fields = dict(STUDIES[name])
        before = fields.pop("extends", None)
        out = work / "runs" / (before or name)
        lake = work / "lake"
        if before and not out.exists():
            path = work / f"{before}.toml"
            path.write_text(BASE.format(**STUDIES[before]))
            sweep(path, lake, out)
        path = work / (f"extended/{before}.toml" if before else f"{name}.toml")  # a study is named after its file
        path.parent.mkdir(exist_ok=True)
        path.write_text(BASE.format(**fields))
        said, _ = sweep(path, lake, out, "--dry-run")
        _, real = sweep(path, lake, out)
        row = {"study": name, "dry_run_s": seconds(said), "real_s": round(real, 1),
               "ratio": round(seconds(said) / real, 2)}  # fmt: skip
        rows.append(row)
        print(json.dumps(row), flush=True)
    ratios = [r["ratio"] for r in rows]
    print(json.dumps({"studies": len(rows), "ratio_min": min(ratios), "ratio_max": max(ratios),
                      "within_30_percent": sum(0.7 <= r <= 1.3 for r in ratios), "work": str(work)}))  # fmt: skip


if __name__ == "__main__":
    main()
