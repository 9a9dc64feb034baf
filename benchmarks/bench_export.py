"""Export speed: transitions/s of `smgen export` for each format, on one lake dataset.

Prints one JSON object (wall and CPU seconds per format; the process's own CPU, so a busy machine
shows in wall time, not in CPU); a format that refuses the dataset says why.
Usage: python benchmarks/bench_export.py DATASET [--lake L]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

from smspace.common.errors import SmspaceError
from smspace.datagen.export import FORMATS, export
from smspace.lake.dataset import Dataset


def cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--lake", default=None)
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    ds = Dataset.open(args.dataset, args.lake)
    out: dict = {"benchmark": "export", "dataset": args.dataset}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in FORMATS:
            cpu0, t0 = cpu_seconds(), time.perf_counter()
            try:
                n = export(ds, fmt, Path(tmp) / fmt, args.limit)
            except SmspaceError as e:  # minari takes walks only
                out[fmt] = {"refused": str(e)}
                continue
            wall, cpu = time.perf_counter() - t0, cpu_seconds() - cpu0
            out[fmt] = {"transitions": n, "wall_s": round(wall, 2), "transitions_per_s": round(n / wall),
                        "transitions_per_cpu_s": round(n / cpu)}  # fmt: skip
    print(json.dumps(out))


if __name__ == "__main__":
    main()
