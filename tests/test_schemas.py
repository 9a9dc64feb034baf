"""The committed generated module is what protoc makes of the committed .proto."""

from __future__ import annotations

from pathlib import Path

from smspace import schemas
from smspace.schemas.build import HERE, generate


def test_generated_module_matches_the_proto(tmp_path):
    generate(tmp_path)
    for name in ("transitions_pb2.py", "transitions_pb2.pyi", "transitions_v2_pb2.py", "transitions_v2_pb2.pyi"):
        assert (tmp_path / name).read_text() == (HERE / name).read_text(), f"run python schemas/build.py ({name})"


def test_schema_version_is_in_the_package_name():
    assert schemas.TransitionBatch.DESCRIPTOR.full_name == f"smspace.v{schemas.SCHEMA_VERSION}.TransitionBatch"
    assert schemas.RegularSampling.DESCRIPTOR.full_name == schemas.REGULAR_SAMPLING
    privileged = schemas.TransitionBatch.DESCRIPTOR.fields_by_name["privileged"].message_type
    assert sorted(privileged.fields_by_name) == ["p_t", "p_t1", "shift_t", "shift_t1"]
    assert Path(HERE / "transitions.proto").exists()
    for version, module in schemas.VERSIONS.items():
        assert module.TransitionBatch.DESCRIPTOR.full_name == schemas.transition_batch_name(version)


def test_version_2_only_adds_the_episodes():
    """Version 2's message reads version 1's bytes: the same fields, numbers and types, plus one."""
    v1, v2 = (schemas.VERSIONS[v].TransitionBatch.DESCRIPTOR for v in (1, 2))
    same = {
        f.name: (f.number, f.type, f.message_type.full_name.split(".")[-1] if f.message_type else None)
        for f in v1.fields
    }
    assert {
        f.name: (f.number, f.type, f.message_type.full_name.split(".")[-1] if f.message_type else None)
        for f in v2.fields
        if f.name != "episodes"
    } == same
    assert v2.fields_by_name["episodes"].number == 11
