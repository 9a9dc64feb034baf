"""Ensemble training speed on one CPU core: FLOPs per step, achieved FLOP/s against the machine's
measured matmul FLOP/s, and the speed-up over training the same runs one after another; the
ensemble as smspace trains it (any model stacked with torch.func) beside the hand-written one it
replaced (benchmarks/old_ensemble.py).

Then the four cells precision × compilation (fp32 / bf16 autocast, eager / torch.compile) of the
step `smtrain sweep` runs (train/precision.py), against this core's fp32 and bf16 matmul peaks,
with the CPU model and its vector extensions; --profile adds each cell's top operators by self
time (what holds it back from the peak of its precision).

Prints one JSON object. The model step is timed on fixed random batches (the loaders cost ~50 µs
per run-step and are reported separately by bench_train.py).
Usage: python benchmarks/bench_ensemble.py [--runs 30 --sensors 4 (grid) | --runs 10 --sensors 768 (arm)] [--profile]
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from bench_train import matmul_flops, step_flops
from old_ensemble import EnsembleNet

from smspace.common.provenance import cpu
from smspace.train.config import TrainConfig
from smspace.train.engine import build, step_loss
from smspace.train.ensemble import Stacked
from smspace.train.model import prediction_loss
from smspace.train.precision import compiled


def seconds_per_step(step, repeats: int, n: int) -> float:
    for _ in range(3):
        step()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(n):
            step()
        best = min(best, (time.perf_counter() - t) / n)
    return best


def cell(runs: int, n_sensor: int, encoder: list[int], precision: str, compile: bool, profile: bool) -> dict:
    cfg = TrainConfig(dataset="bench", encoder_layers=encoder)
    stacked = Stacked([build(cfg, 3, n_sensor, torch.device("cpu"))[0] for _ in range(runs)])
    opt = torch.optim.Adam(stacked.parameters(), lr=1e-3, fused=True)
    xs = [torch.rand(runs, 100, k) * 2 - 1 for k in (3, n_sensor, 3, n_sensor)]
    fn = compiled(step_loss(stacked.forward, precision, torch.device("cpu")), compile)

    def step() -> None:
        total = fn(*xs).sum()
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()

    t = time.perf_counter()
    step()
    first = time.perf_counter() - t
    seconds = seconds_per_step(step, 3, max(5, 3000 // runs))
    out = {"ms_per_run_step": round(seconds * 1e3 / runs, 3), "first_step_s": round(first, 2)}
    if profile:
        with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
            for _ in range(20):
                step()
        rows = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)[:6]
        total = sum(e.self_cpu_time_total for e in prof.key_averages())
        out["top_ops_self_time"] = {e.key: round(e.self_cpu_time_total / total, 3) for e in rows}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--sensors", type=int, default=4, help="4: grid, 768: arm")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="each precision cell's top operators by self time")
    args = ap.parse_args()
    torch.set_num_threads(1)
    peak = matmul_flops()
    bf16_peak = matmul_flops(dtype=torch.bfloat16)
    r, ns, b = args.runs, args.sensors, 100

    cfg = TrainConfig(dataset="bench", encoder_layers=[150, 100, 50])
    single, opt1 = build(cfg, 3, ns, torch.device("cpu"))
    x1 = [torch.rand(b, k) * 2 - 1 for k in (3, ns, 3, ns)]

    def single_step() -> None:
        loss = prediction_loss(single(x1[0], x1[1], x1[2]), x1[3])
        opt1.zero_grad(set_to_none=True)
        loss.backward()
        opt1.step()

    xs = [torch.rand(r, b, k) * 2 - 1 for k in (3, ns, 3, ns)]
    stacked = Stacked([build(cfg, 3, ns, torch.device("cpu"))[0] for _ in range(r)])
    opt = torch.optim.Adam(stacked.parameters(), lr=1e-3, fused=True)
    old = EnsembleNet(r, 3, ns, cfg.n_h, cfg.encoder_layers, cfg.predictor_layers)
    old_opt = torch.optim.Adam(old.parameters(), lr=1e-3, fused=True)

    def step_of(forward, optimizer):
        def step() -> None:
            loss = prediction_loss(forward(xs[0], xs[1], xs[2]), xs[3]).sum()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

        return step

    t_single = seconds_per_step(single_step, args.repeats, 300)
    n = max(5, 3000 // r)
    t_old = seconds_per_step(step_of(old, old_opt), args.repeats, n)  # alternated, so that a noisy
    t_ensemble = seconds_per_step(step_of(stacked.forward, opt), args.repeats, n)  # neighbour hits both
    t_old = min(t_old, seconds_per_step(step_of(old, old_opt), args.repeats, n))
    t_ensemble = min(t_ensemble, seconds_per_step(step_of(stacked.forward, opt), args.repeats, n))
    flops = step_flops(single, b)
    print(
        json.dumps(
            {
                "benchmark": "ensemble",
                "runs": r,
                "n_sensor": ns,
                "threads": 1,
                "matmul_gflops_1core": round(peak / 1e9, 1),
                "mflop_per_run_step": round(flops / 1e6, 1),
                "single_ms_per_step": round(t_single * 1e3, 3),
                "single_fraction_of_peak": round(flops / t_single / peak, 3),
                "ensemble_ms_per_step": round(t_ensemble * 1e3, 2),
                "ensemble_ms_per_run_step": round(t_ensemble * 1e3 / r, 3),
                "handwritten_ensemble_ms_per_run_step": round(t_old * 1e3 / r, 3),
                "torch_func_over_handwritten": round(t_ensemble / t_old, 3),
                "ensemble_gflops": round(r * flops / t_ensemble / 1e9, 1),
                "ensemble_fraction_of_peak": round(r * flops / t_ensemble / peak, 3),
                "speedup_vs_sequential": round(r * t_single / t_ensemble, 2),
                "ms_per_run_step_at_peak": round(flops / peak * 1e3, 3),
                "projected_hours_300_runs_100k_steps": round(300 * 100_000 * t_ensemble / r / 3600, 2),
                **cpu(),
                "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
                "bf16_matmul_gflops_1core": round(bf16_peak / 1e9, 1),
                "precision_cells": precision_cells(r, ns, cfg.encoder_layers, flops, peak, bf16_peak, args.profile),
            }
        )
    )


def precision_cells(runs: int, n_sensor: int, encoder: list[int], flops: float, fp32: float, bf16: float,
                    profile: bool) -> dict:  # fmt: skip
    cells = {}
    for compile in (False, True):
        for precision, peak in (("fp32", fp32), ("bf16", bf16)):
            got = cell(runs, n_sensor, encoder, precision, compile, profile)
            got["fraction_of_peak_of_its_precision"] = round(flops / (got["ms_per_run_step"] / 1e3) / peak, 3)
            cells[f"{'compiled' if compile else 'eager'} {precision}"] = got
    return cells


if __name__ == "__main__":
    main()
