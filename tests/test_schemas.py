"""The committed generated module is what protoc makes of the committed .proto."""

from __future__ import annotations

from pathlib import Path

from smspace import schemas
from smspace.schemas.build import HERE, generate


def test_generated_module_matches_the_proto(tmp_path):
    generate(tmp_path)
    for name in ("transitions_pb2.py", "transitions_pb2.pyi"):
        assert (tmp_path / name).read_text() == (HERE / name).read_text(), f"run python schemas/build.py ({name})"


def test_schema_version_is_in_the_package_name():
    assert schemas.TransitionBatch.DESCRIPTOR.full_name == f"smspace.v{schemas.SCHEMA_VERSION}.TransitionBatch"
    assert schemas.RegularSampling.DESCRIPTOR.full_name == schemas.REGULAR_SAMPLING
    privileged = schemas.TransitionBatch.DESCRIPTOR.fields_by_name["privileged"].message_type
    assert sorted(privileged.fields_by_name) == ["p_t", "p_t1", "shift_t", "shift_t1"]
    assert Path(HERE / "transitions.proto").exists()
