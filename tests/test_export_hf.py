"""`smgen export --format hf`: read back by the Hugging Face `datasets` library's own reader
(load_from_disk), every value equal to the lake's; the dataset card names the license and the
config hash; a failed export leaves nothing, and --overwrite replaces only an earlier export."""

from __future__ import annotations

import datasets
import numpy as np
import pytest
import yaml

from smspace.datagen.export_hf import MARKER, read_hf
from smspace.lake.dataset import Dataset

from .conftest import SAMPLES, smgen


@pytest.mark.parametrize("ds_id", ["arm-seed0-MEM", "grid-seed0-MM"])
def test_hf_export_reads_back_equal_in_datasets(tmp_path, ds_id):
    out = tmp_path / ds_id
    result = smgen("export", ds_id, "--lake", SAMPLES, "--format", "hf", "--out", out)
    assert result.exit_code == 0, result.output
    src = Dataset.open(ds_id, SAMPLES)
    lake = src.read_all()
    hf = datasets.load_from_disk(str(out))
    assert len(hf) == len(lake)
    assert hf.features["m_t"].length == src.manifest.n_motor
    table = hf.with_format("numpy")
    np.testing.assert_array_equal(table["index"], np.arange(len(lake)))
    for name in ("m_t", "m_t1", "p_t", "p_t1", "shift_t", "shift_t1"):
        got = np.asarray(table[name])
        assert got.dtype == np.float32, name
        np.testing.assert_array_equal(got, getattr(lake, name), err_msg=name)
    s = np.asarray(table["s_t1"])
    np.testing.assert_array_equal(s.reshape(lake.s_t1.shape), lake.s_t1)
    stored = hf.data.column("s_t1").type  # the numpy formatter widens integers to int64 on read
    leaf = getattr(stored, "storage_type", stored)
    while hasattr(leaf, "value_type"):
        leaf = leaf.value_type
    assert str(leaf) == {"uint8": "uint8", "float32": "float"}[str(lake.s_t1.dtype)]
    _, back, manifest = read_hf(out)
    for name in lake.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(back, name), getattr(lake, name), err_msg=name)
    assert manifest["config_hash"] == src.manifest.config_hash
    text = (out / "README.md").read_text()
    front = yaml.safe_load(text.split("---")[1])
    assert front["license"] == "mit" and src.manifest.setup in front["tags"]
    assert src.manifest.config_hash in text and "`s_t1`" in text


def test_hf_export_limit_and_overwrite(tmp_path):
    out = tmp_path / "x"
    assert (
        smgen("export", "grid-seed0-MME", "--lake", SAMPLES, "--format", "hf", "--out", out, "--limit", 7).exit_code
        == 0
    )
    assert len(datasets.load_from_disk(str(out))) == 7
    again = smgen("export", "grid-seed0-MME", "--lake", SAMPLES, "--format", "hf", "--out", out)
    assert again.exit_code == 2 and "exists; pass --overwrite" in again.output
    args = ("export", "grid-seed0-MME", "--lake", SAMPLES, "--format", "hf", "--out", out, "--overwrite")
    assert smgen(*args).exit_code == 0 and len(datasets.load_from_disk(str(out))) > 7
    stranger = tmp_path / "mine"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("keep me")
    refused = smgen("export", "grid-seed0-MME", "--lake", SAMPLES, "--format", "hf", "--out", stranger, "--overwrite")
    assert refused.exit_code == 2 and f"no {MARKER}" in refused.output
    assert (stranger / "notes.txt").read_text() == "keep me"


def test_a_failed_hf_export_leaves_nothing(tmp_path, monkeypatch):
    def full_disk(self, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(datasets.Dataset, "save_to_disk", full_disk)
    out = tmp_path / "x"
    result = smgen("export", "grid-seed0-MM", "--lake", SAMPLES, "--format", "hf", "--out", out)
    assert result.exit_code != 0 and "No space left on device" in result.output
    assert list(tmp_path.iterdir()) == []
