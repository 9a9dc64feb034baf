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
import uuid
from dataclasses import dataclass, replace
from functools import cache
from typing import Any

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
    shard), the bytes a stored transition takes, its shapes, and a small dataset of it generated
    in memory (fsspec's memory://, nothing on disk) for the training loop to be timed on."""

    gen_rate: float
    world_s: float  # building a world (a room, a renderer) before its first draw: once per world and worker
    bytes_per_transition: float
    n_sensor: int
    n_regular: int
    p_dims: int
    dataset: Any  # smspace.lake.dataset.Dataset

    @classmethod
    def of(cls, setup: str, seed: int, mode: str, n: int = 512) -> SetupProbe:
        from smspace.datagen.generate import generate
        from smspace.lake.dataset import Dataset
        from smspace.lake.store import open_store

        t = time.perf_counter()
        world = world_for(setup, seed)  # built once, guarded: a plugin's error is one line
        check_world(get_setup(setup), world, seed)  # what generation would refuse, refused here
        world_s = time.perf_counter() - t
        rng = np.random.default_rng(0)
        with plugins.guarded(setup_plugin(setup), f"drawing transitions of world {seed} ({mode})"):
            draw_transitions(world, mode, rng, 16)  # the first draw pays for set-up
            t = time.perf_counter()
            tr = draw_transitions(world, mode, rng, n)
            data = shard_bytes([Block(0, tr)], {})
            seconds = time.perf_counter() - t
            m, p = world.regular_sampling()
        lake = open_store(f"memory://smspace-dry-run-{uuid.uuid4().hex}/lake")
        ((manifest, _),) = generate(lake, setup, [mode], [seed], n, n)
        dataset = Dataset(lake.child(manifest.dataset_id))
        return cls(
            n / max(seconds, 1e-9),
            world_s,
            len(data) / n,
            int(np.prod(world.sensor_shape)),
            len(m),
            p.shape[1],
            dataset,
        )


@dataclass
class EnsembleCost:
    step_s: float  # one step of the training loop for the whole ensemble, its batches' loading included
    evaluation_s: float  # one evaluation of the whole ensemble: forward passes, metrics, checkpoint bytes


def ensemble_cost(template: TrainConfig, n_motor: int, probe: SetupProbe, runs: int) -> EnsembleCost:
    """An ensemble of `runs` of this network in its precision: the engine's own loop timed on the
    probe dataset for two lengths (what both pay, evaluations included, cancels out), and one
    evaluation at the real sizes (random inputs), with the threads a run is given (eager: a
    compiled step would cost its compilation here)."""
    from smspace.train import engine
    from smspace.train.fit import eval_data
    from smspace.train.loader import TransitionStream

    before = torch.get_num_threads()
    torch.set_num_threads(template.threads)
    try:
        cpu = torch.device("cpu")
        cfgs = [replace(template, seed=i, compile="off", loader_workers=0) for i in range(runs)]
        data = eval_data(probe.dataset, template.eval_transitions, cpu)

        def loop(steps: int) -> float:
            members = [
                engine.Member(f"probe-{i}", replace(c, steps=steps, eval_every=steps),
                              TransitionStream(probe.dataset, c.batch_size, seed=c.seed, window=c.shuffle_window), data)
                for i, c in enumerate(cfgs)
            ]  # fmt: skip
            learner = engine.EnsembleLearner([m.cfg for m in members], n_motor, probe.n_sensor, [data] * runs, cpu)
            t = time.perf_counter()
            engine.train(learner, members, 0, progress=False)
            return time.perf_counter() - t

        loop(2)  # warm-up
        short, long = loop(5), loop(25)
        step_s = max(long - short, 0.0) / 20

        def rand(*shape: int) -> torch.Tensor:
            return torch.rand(*shape) * 2 - 1

        k, n = template.eval_transitions, probe.n_sensor
        p_regular = np.random.default_rng(0).random((probe.n_regular, probe.p_dims))
        full = engine.EvalData(rand(probe.n_regular, n_motor), p_regular, *(rand(k, d) for d in (n_motor, n) * 2))
        learner = engine.EnsembleLearner(cfgs, n_motor, n, [full] * runs, cpu)
        t = time.perf_counter()
        losses, hs, _ = learner.evaluate()
        for r in range(runs):
            engine.scores_row(hs[r], full.p_regular, float(losses[r]))
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
