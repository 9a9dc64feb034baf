"""What a dry run measures, here and now, to budget a study: a worker process's start, a setup's
generation rate and stored bytes per transition, an ensemble's training step and its evaluation
(the metrics and the checkpoint included), and how the ensembles share the workers. Every cost is
timed on the code a real run executes; only the data are stand-ins (random batches, a probe
batch of the world), and nothing is written."""

from __future__ import annotations

import heapq
import io
import os
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from functools import cache

import numpy as np
import torch

from smspace.common import plugins
from smspace.datagen.parts import world_for
from smspace.datagen.setups import draw_transitions, get_setup, setup_plugin
from smspace.datagen.setups.contract import check_world
from smspace.lake.shards import Block, shard_bytes
from smspace.train.config import TrainConfig

WORKER_IMPORTS = "import smspace.study.sweep, smspace.train.engine, smspace.train.fit"


@cache
def process_start_s() -> float:
    """Seconds a spawned worker takes before its first step: a new interpreter importing what a
    worker imports (torch included); timed once per dry run."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", WORKER_IMPORTS], check=True, capture_output=True, timeout=300)
    return time.perf_counter() - t


@dataclass
class SetupProbe:
    """What a dry run measures of one setup, once: its generator's rate (drawing and encoding a
    shard), the bytes a stored transition takes, and its shapes."""

    gen_rate: float
    bytes_per_transition: float
    n_sensor: int
    n_regular: int
    p_dims: int

    @classmethod
    def of(cls, setup: str, seed: int, mode: str, n: int = 512) -> SetupProbe:
        world = world_for(setup, seed)  # built once, guarded: a plugin's error is one line
        check_world(get_setup(setup), world, seed)  # what generation would refuse, refused here
        rng = np.random.default_rng(0)
        with plugins.guarded(setup_plugin(setup), f"drawing transitions of world {seed} ({mode})"):
            draw_transitions(world, mode, rng, 16)  # the first draw pays for set-up
            t = time.perf_counter()
            tr = draw_transitions(world, mode, rng, n)
            data = shard_bytes([Block(0, tr)], {})
            seconds = time.perf_counter() - t
            m, p = world.regular_sampling()
        return cls(n / max(seconds, 1e-9), len(data) / n, int(np.prod(world.sensor_shape)), len(m), p.shape[1])


@dataclass
class EnsembleCost:
    step_s: float  # one training step of the whole ensemble
    evaluation_s: float  # one evaluation of the whole ensemble: forward passes, metrics, checkpoint bytes


def ensemble_cost(template: TrainConfig, n_motor: int, probe: SetupProbe, runs: int, steps: int = 10) -> EnsembleCost:
    """An ensemble of `runs` of this network in its precision, timed on random batches with the
    threads a run is given (eager: a compiled step would cost its compilation here)."""
    from smspace.train.engine import EnsembleLearner, EvalData, scores_row

    before = torch.get_num_threads()
    torch.set_num_threads(template.threads)
    try:

        def rand(*shape: int) -> torch.Tensor:
            return torch.rand(*shape) * 2 - 1

        cfgs = [replace(template, seed=i, compile=False) for i in range(runs)]
        k, n = template.eval_transitions, probe.n_sensor
        data = [
            EvalData(rand(probe.n_regular, n_motor), np.random.default_rng(0).random((probe.n_regular, probe.p_dims)),
                     rand(k, n_motor), rand(k, n), rand(k, n_motor), rand(k, n))
        ] * runs  # fmt: skip
        learner = EnsembleLearner(cfgs, n_motor, n, data, torch.device("cpu"))  # the sweep's own step
        batch = tuple(rand(template.batch_size, d) for d in (n_motor, n) * 2)
        learner.train_step([batch] * runs)
        t = time.perf_counter()
        for _ in range(steps):
            learner.train_step([batch] * runs)
        step_s = (time.perf_counter() - t) / steps
        t = time.perf_counter()
        losses, hs, _ = learner.evaluate()
        for r in range(runs):
            scores_row(hs[r], data[r].p_regular, float(losses[r]))
            torch.save(learner.state_of(r, template.lr_start), io.BytesIO())
        return EnsembleCost(step_s, time.perf_counter() - t)
    finally:
        torch.set_num_threads(before)


def makespan(durations: list[float], workers: int) -> float:
    """Wall time of tasks, in the sweep's order, shared by `workers` that each take the next one
    as they free up."""
    lanes = [0.0] * max(1, min(workers, len(durations)))
    for d in durations:
        heapq.heapreplace(lanes, lanes[0] + d)
    return max(lanes, default=0.0)


def contention(workers: int, threads: int) -> float:
    """How much slower each step runs when the workers' threads outnumber the cores."""
    return max(1.0, workers * threads / (os.cpu_count() or 1))
