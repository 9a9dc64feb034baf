"""Train the sensorimotor predictive network on one dataset (SPEC 3), top to bottom.

Evaluates at step 0 and every `eval_every` steps (loss, D_topo, D_metric, lr), writes the learned
h of the regular sampling each time, and checkpoints atomically right after, so `--resume`
continues from the last evaluation and ends bit-identical to an uninterrupted run on the CPU.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from datagen.errors import SmspaceError
from datagen.lake.dataset import Dataset
from train.config import TrainConfig, learning_rate
from train.evaluation import N_PREDICTIONS, EvalData, scores_row, write_evaluation
from train.loader import TransitionStream
from train.model import SensorimotorNet, prediction_loss
from train.run_dir import RunDir


class TrainingFailed(SmspaceError):
    """Training itself went wrong (NaN loss); the last good checkpoint is kept."""

    exit_code = 1


def resolve_device(name: str) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise SmspaceError(f"--device cuda: no CUDA GPU is usable here (torch {torch.__version__})")
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise SmspaceError(f"unknown --device {name!r} (cpu or cuda)")
    return torch.device(name)


@torch.no_grad()
def evaluate(model: SensorimotorNet, data: EvalData) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    h = model.encode(data.m_regular).double().cpu().numpy()
    pred = model(data.m_t, data.s_t, data.m_t1)
    loss = float(prediction_loss(pred, data.s_t1))
    return scores_row(h, data.p_regular, loss), h, pred[:N_PREDICTIONS].cpu().numpy()


def build(cfg: TrainConfig, n_motor: int, n_sensor: int, device: torch.device):
    torch.manual_seed(cfg.seed)
    model = SensorimotorNet(n_motor, n_sensor, cfg.n_h, cfg.encoder_layers or None, cfg.predictor_layers).to(device)
    # fused Adam: one kernel for all parameters, 1.5-2x faster steps than the per-tensor loop on a CPU
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr_start, betas=(0.9, 0.999), eps=1e-8, fused=True)
    return model, optimizer


def fit(cfg: TrainConfig, run: RunDir, resume: bool = False) -> dict[str, Any]:
    torch.set_num_threads(cfg.threads)  # 2 cores: oversubscribed threads made steps 10-40x slower
    device = resolve_device(cfg.device)
    ds = Dataset(cfg.dataset)
    for path, shard in zip(ds.shard_paths(), ds.manifest.shards, strict=True):
        if not path.exists() or path.stat().st_size != shard["bytes"]:
            raise SmspaceError(f"shard {path} is missing or not the size its manifest records")
    n_sensor = int(np.prod(ds.manifest.sensor_shape))
    model, optimizer = build(cfg, ds.manifest.n_motor, n_sensor, device)
    stream = TransitionStream(ds, cfg.batch_size, seed=cfg.seed, window=cfg.shuffle_window)
    data = EvalData.load(ds, cfg.eval_transitions, device)

    step, rows, elapsed = 0, [], 0.0
    if resume:
        ckpt = run.load_checkpoint(str(device))
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        stream.load_state_dict(ckpt["stream"])
        step, elapsed = int(ckpt["step"]), float(ckpt["elapsed_s"])
        rows = [r for r in run.metrics() if r["step"] <= step]
        run.truncate_after(step)

    def record(step: int, train_loss: float) -> dict[str, Any]:
        scores, h, pred = evaluate(model, data)
        row = {"step": step, "lr": learning_rate(cfg, step), "train_loss": train_loss, **scores, "elapsed_s": elapsed}
        checkpoint = {
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "stream": stream.state_dict(),
            "step": step,
            "elapsed_s": elapsed,
        }
        write_evaluation(run, rows, row, h, data, pred, checkpoint)
        return row

    if step == 0:
        record(0, math.nan)
    loader = DataLoader(stream, batch_size=None, num_workers=cfg.loader_workers)
    batches = iter(loader)
    check_each_step = device.type == "cpu"  # .item() is free on a CPU, a sync on a GPU
    loss_sum = torch.zeros((), device=device)
    loss_count = 0
    bar = tqdm(total=cfg.steps, initial=step, unit="step", disable=None, file=sys.stderr, desc="training")
    try:
        t0 = time.perf_counter()
        while step < cfg.steps:
            lr = learning_rate(cfg, step)
            for group in optimizer.param_groups:
                group["lr"] = lr
            m_t, s_t, m_t1, s_t1 = (x.to(device, non_blocking=True) for x in next(batches))
            loss = prediction_loss(model(m_t, s_t, m_t1), s_t1)
            if check_each_step and not math.isfinite(loss.item()):
                raise _diverged(step, rows)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            step += 1
            stream.batches_consumed = step
            loss_sum += loss.detach()
            loss_count += 1
            bar.update()
            if step % cfg.eval_every == 0 or step == cfg.steps:
                train_loss = float(loss_sum) / loss_count
                if not math.isfinite(train_loss):
                    raise _diverged(step, rows)
                elapsed += time.perf_counter() - t0
                row = record(step, train_loss)
                t0 = time.perf_counter()
                loss_sum.zero_()
                loss_count = 0
                bar.set_postfix(
                    loss=f"{row['eval_loss']:.4g}", D_topo=f"{row['d_topo']:.3g}", D_metric=f"{row['d_metric']:.3g}"
                )
    except SmspaceError as e:
        run.set_status("failed", rows[-1]["step"] if rows else 0, str(e))
        raise
    except KeyboardInterrupt:
        run.set_status("interrupted", rows[-1]["step"] if rows else 0, "interrupted; resume with --resume")
        raise
    finally:
        bar.close()
    run.set_status("finished", step)
    return rows[-1]


def _diverged(step: int, rows: list[dict[str, Any]]) -> TrainingFailed:
    last = rows[-1]["step"] if rows else 0
    return TrainingFailed(f"loss became NaN or inf at step {step}; stopped, the checkpoint of step {last} is kept")
