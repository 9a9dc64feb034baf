"""Training speed on one CPU core: steps/s of the paper's configuration against the machine's
matmul FLOP/s, and loader throughput against what the trainer consumes. Prints one JSON object.

Usage: python benchmarks/bench_train.py [--steps 2000]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from smspace.datagen.generate import generate
from smspace.lake.dataset import Dataset
from smspace.train.config import TrainConfig
from smspace.train.engine import build
from smspace.train.loader import TransitionStream
from smspace.train.model import prediction_loss


def matmul_flops(n: int = 1024, repeats: int = 5, dtype: torch.dtype = torch.float32) -> float:
    """The FLOP/s of one large matmul in `dtype` on this thread: the peak a step is measured against."""
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(10):
            torch.mm(a, b)
        best = min(best, (time.perf_counter() - t) / 10)
    return 2 * n**3 / best


def step_flops(model: torch.nn.Module, batch: int) -> float:
    """Forward matmul FLOPs × 3 (forward, grad of inputs, grad of weights): the usual estimate."""
    forward = 0
    for net, rows in ((model.encoder, 2 * batch), (model.predictor, batch)):
        forward += sum(2 * rows * m.in_features * m.out_features for m in net if hasattr(m, "out_features"))
    return 3.0 * forward


def model_steps_per_s(n_sensor: int, steps: int, batch: int = 100) -> tuple[float, float]:
    model, opt = build(
        TrainConfig(dataset="bench", batch_size=batch, encoder_layers=[150, 100, 50]),
        3,
        n_sensor,
        torch.device("cpu"),
    )
    data = [torch.rand(batch, k) * 2 - 1 for k in (3, n_sensor, 3, n_sensor)]
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(steps):
            loss = prediction_loss(model(data[0], data[1], data[2]), data[3])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        best = min(best, (time.perf_counter() - t) / steps)
    return 1 / best, step_flops(model, batch)


def loader_transitions_per_s(dataset: Dataset, batches: int) -> float:
    it = iter(TransitionStream(dataset, batch_size=100, seed=0))
    next(it)
    t = time.perf_counter()
    for _ in range(batches):
        next(it)
    return batches * 100 / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    peak = matmul_flops()
    out: dict = {"benchmark": "train", "threads": 1, "matmul_gflops_1core": round(peak / 1e9, 1)}
    for name, n_sensor in (("grid", 4), ("arm", 768)):
        sps, flops = model_steps_per_s(n_sensor, args.steps)
        out[name] = {
            "n_sensor": n_sensor,
            "steps_per_s": round(sps, 1),
            "ms_per_step": round(1e3 / sps, 3),
            "mflop_per_step": round(flops / 1e6, 1),
            "achieved_gflops": round(sps * flops / 1e9, 1),
            "fraction_of_matmul_peak": round(sps * flops / peak, 3),
            "ms_per_step_at_peak": round(1e3 * flops / peak, 3),
        }
    with tempfile.TemporaryDirectory() as tmp:
        generate(Path(tmp), "grid", ["MME"], [0], 150_000, 32768)
        ds = Dataset(Path(tmp) / "grid-seed0-MME")
        tps = loader_transitions_per_s(ds, 5000)
    out["loader_grid_transitions_per_s"] = round(tps)
    out["trainer_grid_transitions_per_s"] = round(out["grid"]["steps_per_s"] * 100)
    out["loader_over_trainer"] = round(tps / out["trainer_grid_transitions_per_s"], 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
