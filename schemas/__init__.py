"""Protobuf schemas of the smspace data lake. `transitions.proto` is the source of truth."""

from smspace.schemas import transitions_pb2

SCHEMA_VERSION = 1
PACKAGE = "smspace.v1"
TRANSITION_BATCH = f"{PACKAGE}.TransitionBatch"
REGULAR_SAMPLING = f"{PACKAGE}.RegularSampling"

TransitionBatch = transitions_pb2.TransitionBatch
RegularSampling = transitions_pb2.RegularSampling

__all__ = [
    "PACKAGE",
    "REGULAR_SAMPLING",
    "SCHEMA_VERSION",
    "TRANSITION_BATCH",
    "RegularSampling",
    "TransitionBatch",
]
