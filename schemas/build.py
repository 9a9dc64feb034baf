"""Regenerate transitions_pb2.py and transitions_v2_pb2.py from their .proto files (needs
grpcio-tools, a dev dependency).

The .proto is the source of truth; the generated module is committed so that users need no
protobuf compiler, and tests/test_schemas.py fails when the two drift apart.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROTOS = ("transitions.proto", "transitions_v2.proto")


def generate(out_dir: Path) -> None:
    from grpc_tools import protoc

    args = [
        "protoc",
        f"-I{HERE}",
        f"--python_out={out_dir}",
        f"--pyi_out={out_dir}",
        *(str(HERE / name) for name in PROTOS),
    ]
    if protoc.main(args) != 0:
        raise SystemExit("protoc failed")


if __name__ == "__main__":
    generate(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
