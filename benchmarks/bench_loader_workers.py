"""Batches per second that reach a user's own loop from `TransitionStream`: read in the process
itself, and through `DataLoader(stream, batch_size=None, num_workers=W)` for W = 0, 1, 2 (issue 30
asked that workers never be slower than none). One grid dataset of the default size is generated
first; each case draws `--batches` batches of 100 after a warm-up (6000: four epochs of its 150000
transitions), best of `--repeats`.

Then the same sources feed a user's loop that trains the lone run's network on each batch
(`--steps` steps): what workers do to the loop, not to the loader alone.

`--loader FILE` times another version of train/loader.py instead of this checkout's, for a before
and after (e.g. `git show f1174be:train/loader.py > /tmp/before.py`).
Prints one JSON object; say what else ran beside it.
Usage: python benchmarks/bench_loader_workers.py [--batches 6000] [--steps 1500] [--repeats 2] [--loader FILE]
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

BIN = Path(sys.executable).parent


def stream_class(loader_file: str | None):
    if loader_file is None:
        from smspace.train.loader import TransitionStream

        return TransitionStream
    spec = importlib.util.spec_from_file_location("loader_under_test", loader_file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module.TransitionStream


def rate(make_iter, batches: int, repeats: int, step=None) -> float:
    """Best batches (or steps) per second over `repeats` fresh iterators."""
    best = 0.0
    for _ in range(repeats):
        it = make_iter()
        for _ in itertools.islice(it, 200):  # workers started, first windows read
            pass
        t = time.perf_counter()
        for batch in itertools.islice(it, batches):
            if step is not None:
                step(batch)
        best = max(best, batches / (time.perf_counter() - t))
        del it
    return best


def training_step():
    """The lone run's step of `smtrain fit` (the paper's grid network, Adam): a user's loop."""
    from smspace.train.config import TrainConfig
    from smspace.train.engine import build, step_loss

    model, optimizer = build(TrainConfig(dataset="bench", encoder_layers=[150, 100, 50]), 3, 4, torch.device("cpu"))
    loss_of = step_loss(model, "fp32", torch.device("cpu"))

    def step(batch) -> None:
        loss = loss_of(*batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    return step


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batches", type=int, default=6000)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--steps", type=int, default=1500, help="steps of the loop with a training step")
    ap.add_argument("--loader", help="another train/loader.py to time")
    args = ap.parse_args()
    torch.set_num_threads(1)
    stream = stream_class(args.loader)
    with tempfile.TemporaryDirectory() as tmp:
        generate = [BIN / "smgen", "generate", "--setup", "grid", "--mode", "MM", "--worlds", 1, "--lake", tmp]
        subprocess.run([str(x) for x in generate], check=True, capture_output=True)
        dataset = Path(tmp) / "grid-seed0-MM"
        cases = {"in the process (iter(stream))": lambda: iter(stream(dataset, batch_size=100, seed=1))}
        for workers in (0, 1, 2):
            cases[f"DataLoader, num_workers={workers}"] = lambda w=workers: iter(
                DataLoader(stream(dataset, batch_size=100, seed=1), batch_size=None, num_workers=w)
            )
        if args.loader is None:  # many batches per queue item, in the DataLoader's order
            from smspace.train.worker_batches import worker_batches

            for workers in (1, 2):
                cases[f"worker_batches, num_workers={workers}"] = lambda w=workers: worker_batches(
                    stream(dataset, batch_size=100, seed=1), w
                )
        rates = {name: round(rate(make, args.batches, args.repeats)) for name, make in cases.items()}
        step = training_step()
        loops = {name: round(rate(make, args.steps, args.repeats, step)) for name, make in cases.items()}
    print(
        json.dumps(
            {
                "benchmark": "loader_workers",
                "loader": args.loader or "this checkout",
                "batch_size": 100,
                "batches_per_s": rates,
                "training_steps_per_s": loops,
                "sharing_strategy": torch.multiprocessing.get_sharing_strategy(),
            }
        )
    )


if __name__ == "__main__":
    main()
