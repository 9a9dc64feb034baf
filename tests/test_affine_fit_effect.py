"""scripts/affine_fit_effect.py, which backs docs/REPRODUCTION.md's word that the N_h = 25 table
stands under today's affine fit: it must score a run as training did, and see a change where the
two fits differ."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import smspace
from smspace.datagen.setups.grid import GridWorld

from .conftest import ROOT, SAMPLES

sys.path.insert(0, str(ROOT / "scripts"))
from affine_fit_effect import former_d_metric


def test_it_scores_a_trained_run_as_training_did(tmp_path):
    run = smspace.fit(SAMPLES / "grid-seed0-MME", out=tmp_path / "runs" / "r", steps=60, eval_every=30, n_h=3)
    out = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "affine_fit_effect.py"), str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    report = json.loads(out.stdout)
    (row,) = report["runs"]
    recorded = run.metrics()[-1]
    assert (row["mode"], row["step"], row["n_h"]) == ("MME", 60, 3)
    assert row["d_metric"] == pytest.approx(recorded["d_metric"], rel=1e-9)
    assert row["d_metric_former_fit"] == pytest.approx(row["d_metric"], rel=1e-6)  # a 3-D h: full rank
    assert report["modes"]["MME"]["runs"] == 1


def test_the_former_fit_differs_where_h_has_a_thin_direction():
    rng = np.random.default_rng(3)
    p = GridWorld(0).positions
    m = rng.normal(size=(len(p), 2))
    h = (m @ rng.normal(size=(2, 3)) + 0.5).astype(np.float32)  # rank 2 in 3 dimensions, rounded
    h = h + (rng.normal(size=h.shape) * 1e-6).astype(np.float32)  # a thin third direction
    full_rank = rng.normal(size=(len(p), 3))
    assert former_d_metric(full_rank, p) == pytest.approx(smspace.spatial_scores(full_rank, p).d_metric, rel=1e-9)
    assert (
        abs(former_d_metric(h, p) - smspace.spatial_scores(h, p).d_metric)
        > 1e-3 * smspace.spatial_scores(h, p).d_metric
    )
