"""`smgen export --format minari`: a walk dataset read back by `minari.load_dataset`, episode by
episode, every value equal to the lake's (arm frames lossless); independent transitions are refused
in one line; a failed export leaves nothing. The hf export of a walk carries episode and step."""

from __future__ import annotations

import datasets
import minari
import numpy as np
import pytest

from smspace.datagen.export_minari import minari_id, read_minari
from smspace.lake.dataset import Dataset

from .conftest import SAMPLES, failed_in_one_line, smgen

WALK = ["--exploration", "walk", "--mode", "MME"]


@pytest.fixture(scope="module")
def walk_lake(tmp_path_factory):
    lake = tmp_path_factory.mktemp("walks")
    grid = smgen("generate", "--setup", "grid", *WALK, "--walk-length", 25, "--transitions", 1000,
                 "--shard-size", 500, "--lake", lake)  # fmt: skip
    arm = smgen("generate", "--setup", "arm", *WALK, "--walk-length", 8, "--transitions", 48,
                "--shard-size", 24, "--lake", lake)  # fmt: skip
    assert grid.exit_code == 0 and arm.exit_code == 0, grid.output + arm.output
    return lake


@pytest.mark.parametrize(("ds_id", "length"), [("grid-seed0-MME-walk", 25), ("arm-seed0-MME-walk", 8)])
def test_minari_export_reads_back_equal_in_minari(walk_lake, tmp_path, ds_id, length):
    out = tmp_path / "minari"
    result = smgen("export", ds_id, "--lake", walk_lake, "--format", "minari", "--out", out)
    assert result.exit_code == 0, result.output
    src = Dataset.open(ds_id, walk_lake)
    lake = src.read_all()
    ids, lengths, back = read_minari(out, ds_id)
    assert ids == list(range(len(lake) // length)) and set(lengths) == {length}
    for name in lake.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(back, name), getattr(lake, name), err_msg=name)
        assert getattr(back, name).dtype == getattr(lake, name).dtype, name
    # what minari itself says of the dataset
    import os

    os.environ["MINARI_DATASETS_PATH"] = str(out)
    try:
        dataset = minari.load_dataset(minari_id(ds_id))
        assert dataset.total_episodes == len(lake) // length and dataset.total_steps == len(lake)
        assert src.manifest.config_hash in dataset.storage.metadata["description"]
        assert dataset.storage.metadata["jpeg_encoding"] is False
        episode = next(dataset.iterate_episodes())
        assert episode.truncations[-1] and not episode.truncations[:-1].any() and not episode.terminations.any()
    finally:
        del os.environ["MINARI_DATASETS_PATH"]


def test_minari_refuses_independent_transitions_and_a_failed_export_leaves_nothing(walk_lake, tmp_path, monkeypatch):
    out = tmp_path / "m"
    line = failed_in_one_line(smgen("export", "grid-seed0-MM", "--lake", SAMPLES, "--format", "minari", "--out", out))
    assert "independent transitions" in line and not out.exists()

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(minari, "create_dataset_from_buffers", full_disk)
    result = smgen("export", "grid-seed0-MME-walk", "--lake", walk_lake, "--format", "minari", "--out", out)
    assert result.exit_code != 0 and "No space left on device" in result.output
    assert list(tmp_path.iterdir()) == []


def test_hf_export_of_a_walk_carries_episode_and_step(walk_lake, tmp_path):
    out = tmp_path / "hf"
    assert smgen("export", "grid-seed0-MME-walk", "--lake", walk_lake, "--format", "hf", "--out", out).exit_code == 0
    table = datasets.load_from_disk(str(out)).with_format("numpy")
    episode, step = Dataset.open("grid-seed0-MME-walk", walk_lake).episodes()
    np.testing.assert_array_equal(table["episode"], episode)
    np.testing.assert_array_equal(table["step"], step)
