"""Logging a dataset to an .rrd with `smgen view --save` (column-wise send_columns).

Prints one JSON object: seconds to read + log N transitions, the .rrd size. Generation of the
dataset is not timed. Usage: python benchmarks/bench_view.py [--setup grid] [--transitions 150000] [--dataset FOLDER]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from smspace.common.rerun_output import ViewOutput
from smspace.datagen.generate import generate
from smspace.datagen.setups import get_setup
from smspace.datagen.view import view_dataset
from smspace.lake.dataset import Dataset


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--setup", default="grid")
    ap.add_argument("--transitions", type=int, default=150_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dataset", type=Path, default=None, help="An existing dataset folder (nothing is generated).")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.dataset is None:
            shard = get_setup(args.setup).default_shard_size
            generate(Path(tmp), args.setup, ["MME"], [0], args.transitions, shard, workers=args.workers)
            ds = Dataset(Path(tmp) / f"{args.setup}-seed0-MME")
        else:
            ds = Dataset(args.dataset)
        out = Path(tmp) / "view.rrd"
        t0 = time.perf_counter()
        n = view_dataset(ds, None, ViewOutput(save=out))
        seconds = time.perf_counter() - t0
        size = out.stat().st_size
    print(
        json.dumps(
            {
                "benchmark": "view",
                "setup": ds.manifest.setup,
                "transitions": n,
                "seconds": round(seconds, 2),
                "transitions_per_s": round(n / seconds),
                "rrd_bytes": size,
            }
        )
    )


if __name__ == "__main__":
    main()
