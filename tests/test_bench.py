"""smspace-bench: its baselines (bench/entries.py), suites, runner and leaderboard."""

from __future__ import annotations

import math

import pytest
import torch

from smspace.lake.dataset import Dataset
from smspace.train.config import TrainConfig
from smspace.train.engine import build
from smspace.train.fit import fit, train_ensemble
from smspace.train.run_dir import RunDir

from .conftest import SAMPLES
from .numerics import assert_same_weights

BASELINES = ["random-encoder", "motor-autoencoder", "contrastive"]


def config(model: str, seed: int = 3, mode: str = "MM", steps: int = 40) -> TrainConfig:
    ds = SAMPLES / f"grid-seed0-{mode}"
    return TrainConfig(dataset=str(ds), dataset_id=ds.name, steps=steps, eval_every=20, seed=seed, model=model)


def weights(run: RunDir) -> dict[str, torch.Tensor]:
    return torch.load(run.local_path / "checkpoint.pt", weights_only=True)["model"]


@pytest.mark.parametrize("model", BASELINES)
def test_a_baseline_trains_on_its_own_objective_alone_and_in_an_ensemble(tmp_path, model):
    """Each baseline trains its objective (its loss falls), the same alone as stacked in a sweep's
    ensemble, and leaves untrained what it must (the random encoder's encoder)."""
    cfgs = [config(model, seed=3), config(model, seed=4, mode="MME")]
    alone = RunDir.create(tmp_path / "alone", cfgs[0], False)
    fit(cfgs[0], alone)
    members = [RunDir.create(tmp_path / f"member{i}", c, False) for i, c in enumerate(cfgs)]
    train_ensemble(members, progress=False)
    assert_same_weights(weights(alone), weights(members[0]), "MM")
    rows = alone.metrics()
    assert rows[-1]["train_loss"] < rows[1]["train_loss"] or model == "random-encoder", rows
    manifest = Dataset.open(cfgs[0].dataset).manifest
    initial = build(alone.config, manifest.n_motor, math.prod(manifest.sensor_shape), torch.device("cpu"))[0].state_dict()
    moved = {k for k, v in weights(alone).items() if not torch.equal(v, initial[k])}
    if model == "random-encoder":
        assert moved and not any(k.startswith("encoder") for k in moved), moved
    else:
        assert any(k.startswith("encoder") for k in moved), moved


def test_the_baselines_are_registered_as_plugins_are():
    from smspace.train.model import model_plugin

    for name in BASELINES:
        plugin = model_plugin(name)
        assert plugin is not None and plugin.distribution == "smspace" and len(plugin.code_sha256) == 16, plugin
