"""The committed samples are exactly what their recorded command generates."""

from __future__ import annotations

import json
import shlex

import pyarrow.parquet as pq
import pytest

from .conftest import SAMPLES, smgen


def recorded_commands() -> list[list[str]]:
    text = (SAMPLES / "README.md").read_text()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith("smgen generate")]
    return [shlex.split(line)[1:] for line in lines]


@pytest.mark.numerical  # numpy's SIMD dispatch differs between CPU kinds
def test_samples_regenerate_byte_identical(tmp_path):
    commands = recorded_commands()
    assert len(commands) == 2
    for args in commands:
        args[args.index("--lake") + 1] = str(tmp_path)
        result = smgen(*args)
        assert result.exit_code == 0, result.output
    committed = sorted(p.relative_to(SAMPLES) for p in SAMPLES.rglob("*.mcap"))
    assert len(committed) == 18
    assert committed == sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*.mcap"))
    for rel in committed:
        assert (tmp_path / rel).read_bytes() == (SAMPLES / rel).read_bytes(), rel
    for folder in [*SAMPLES.glob("grid-*"), *SAMPLES.glob("arm-*")]:
        a = json.loads((folder / "manifest.json").read_text())
        b = json.loads((tmp_path / folder.name / "manifest.json").read_text())
        a.pop("software"), b.pop("software")  # library versions may move; the data may not
        assert a == b
    assert pq.read_table(SAMPLES / "catalog.parquet").equals(pq.read_table(tmp_path / "catalog.parquet"))


def test_samples_validate():
    ids = [p.parent.name for p in sorted(SAMPLES.glob("*/manifest.json"))]
    assert len(ids) == 6
    result = smgen("validate", "--lake", SAMPLES, *ids)
    assert result.exit_code == 0, result.output
