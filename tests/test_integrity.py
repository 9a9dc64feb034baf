"""Bytes that are not the recorded ones are never trained on, exported or shown, and `generate`
repairs them instead of calling the dataset complete (lake/integrity.py)."""

from __future__ import annotations

import gc
import json
import shutil
from functools import partial
from pathlib import Path

import pytest

from .conftest import SAMPLES, SHARD, failed_in_one_line, forged, smgen, smtrain


@pytest.fixture()
def tampered(tmp_path) -> Path:
    lake = tmp_path / "lake"
    shutil.copytree(SAMPLES, lake)
    path = lake / "grid-seed0-MEM" / SHARD
    original = path.read_bytes()
    path.write_bytes(forged(original, path.parent))
    assert path.stat().st_size == len(original) and path.read_bytes() != original
    return lake


one_line = partial(failed_in_one_line, code=2, alone=True)  # one_line(result, prog)


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")  # a writer left open on the way out
def test_a_forged_shard_of_the_same_size_is_never_trained_on_exported_or_shown(tampered, tmp_path):
    line = one_line(
        smtrain("fit", "grid-seed0-MEM", "--lake", tampered, "--out", tmp_path / "run", "--steps", 300), "smtrain"
    )
    assert SHARD in line and "sha256" in line and not (tmp_path / "run").exists()
    for args in (
        ["export", "grid-seed0-MEM", "--format", "parquet", "--out", tmp_path / "x.parquet"],
        ["view", "grid-seed0-MEM", "--save", tmp_path / "x.rrd"],
    ):
        assert SHARD in one_line(smgen(*args, "--lake", tampered), "smgen")
    gc.collect()
    assert not (tmp_path / "x.parquet").exists() and not (tmp_path / "x.rrd").exists()


def test_generate_repairs_a_forged_shard_instead_of_calling_the_dataset_complete(tampered):
    args = ["generate", "--setup", "grid", "--mode", "MEM", "--transitions", 4096, "--shard-size", 2048]
    result = smgen(*args, "--lake", tampered)
    assert result.exit_code == 0, result.output
    assert f"grid-seed0-MEM: {SHARD}: its bytes differ from the manifest's sha256" in result.output
    assert "drawing it again" in result.output and "\twritten" in result.output
    assert (tampered / "grid-seed0-MEM" / SHARD).read_bytes() == (SAMPLES / "grid-seed0-MEM" / SHARD).read_bytes()
    assert json.loads((tampered / "grid-seed0-MEM" / "manifest.json").read_text()) == json.loads(
        (SAMPLES / "grid-seed0-MEM" / "manifest.json").read_text()
    ) | {"software": json.loads((tampered / "grid-seed0-MEM" / "manifest.json").read_text())["software"]}
    again = smgen(*args, "--lake", tampered)
    assert again.exit_code == 0 and "\texists" in again.output and "drawing" not in again.output


def test_manifests_record_the_md5_object_storage_reports_for_one_put():
    import hashlib

    manifest = json.loads((SAMPLES / "grid-seed0-MM" / "manifest.json").read_text())
    for entry in [*manifest["shards"], manifest["regular_sampling"]]:
        data = (SAMPLES / "grid-seed0-MM" / entry["file"]).read_bytes()
        assert entry["md5"] == hashlib.md5(data).hexdigest() and entry["sha256"] == hashlib.sha256(data).hexdigest()
