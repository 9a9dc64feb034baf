"""Every run folder holds TensorBoard files (train/tensorboard.py), read back here with
tensorboard's own readers: the scalars are the metrics table's, step by step, and the projector
shows h of the last evaluation with p as its metadata."""

from __future__ import annotations

import math

import numpy as np
from google.protobuf import text_format
from tensorboard.plugins.projector.projector_config_pb2 import ProjectorConfig

from smspace.train.run_dir import RunView

from .conftest import SAMPLES, board_scalars, smtrain

COLUMNS = {"loss/eval": "eval_loss", "loss/train": "train_loss", "space/D_topo": "d_topo",
           "space/D_metric": "d_metric", "lr": "lr"}  # fmt: skip


def test_a_run_s_tensorboard_files_hold_its_metrics_and_its_learned_space(tmp_path):
    out = tmp_path / "run"
    result = smtrain("fit", "grid-seed0-MME", "--lake", SAMPLES, "--out", out, "--steps", 300, "--eval-every", 100)
    assert result.exit_code == 0, result.output
    rows = RunView.open(out).metrics()
    scalars = board_scalars(out)
    assert set(scalars) == set(COLUMNS)
    for tag, column in COLUMNS.items():
        expected = [(r["step"], r[column]) for r in rows if math.isfinite(r[column])]
        assert [s for s, _ in scalars[tag]] == [s for s, _ in expected], tag
        np.testing.assert_allclose([v for _, v in scalars[tag]], [v for _, v in expected], rtol=1e-6, err_msg=tag)
    assert [s for s, _ in scalars["loss/train"]] == [100, 200, 300]  # step 0 has no training loss

    board = out  # the projector looks beside the run's event stream
    config = text_format.Parse((board / "projector_config.pbtxt").read_text(), ProjectorConfig())
    (embedding,) = config.embeddings
    assert embedding.tensor_name == "h (step 300)"
    h, p = RunView.open(out).embeddings(300)
    tensors = np.loadtxt(board / embedding.tensor_path, delimiter="\t", ndmin=2)
    np.testing.assert_allclose(tensors, h, rtol=1e-6, atol=1e-7)
    meta = np.loadtxt(board / embedding.metadata_path, delimiter="\t", skiprows=1, ndmin=2)
    header = (board / embedding.metadata_path).read_text().splitlines()[0].split("\t")
    assert header == ["index", "p_x", "p_y", "step"]
    np.testing.assert_allclose(meta[:, 1:3], p, rtol=1e-6)
    assert (meta[:, 3] == 300).all() and len(meta) == len(h)
