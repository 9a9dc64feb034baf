"""Protobuf schemas of the smspace data lake. The .proto files are the source of truth.

Version 1 holds independent transitions; version 2 adds each transition's episode and step, for
walks. Datasets of transitions are still written in version 1 (their bytes unchanged), walks in
version 2; every readable version is read.
"""

from smspace.schemas import transitions_pb2, transitions_v2_pb2

VERSIONS = {1: transitions_pb2, 2: transitions_v2_pb2}
READABLE = tuple(VERSIONS)
TRANSITIONS_VERSION = 1  # what a dataset of independent transitions is written in
WALKS_VERSION = 2
SCHEMA_VERSION = TRANSITIONS_VERSION  # kept for readers of version 1 only


def package(version: int) -> str:
    return f"smspace.v{version}"


def transition_batch_name(version: int) -> str:
    return f"{package(version)}.TransitionBatch"


def regular_sampling_name(version: int) -> str:
    return f"{package(version)}.RegularSampling"


PACKAGE = package(TRANSITIONS_VERSION)
TRANSITION_BATCH = transition_batch_name(TRANSITIONS_VERSION)
REGULAR_SAMPLING = regular_sampling_name(TRANSITIONS_VERSION)

TransitionBatch = transitions_pb2.TransitionBatch
RegularSampling = transitions_pb2.RegularSampling

__all__ = [
    "PACKAGE",
    "READABLE",
    "REGULAR_SAMPLING",
    "SCHEMA_VERSION",
    "TRANSITIONS_VERSION",
    "TRANSITION_BATCH",
    "VERSIONS",
    "WALKS_VERSION",
    "RegularSampling",
    "TransitionBatch",
    "package",
    "regular_sampling_name",
    "transition_batch_name",
]
