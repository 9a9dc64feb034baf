"""Shared helpers: run the CLIs in-process or as real subprocesses, and tiny generated lakes."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "data" / "samples"
BIN = Path(sys.executable).parent


GRID = ["--setup", "grid", "--transitions", "6000", "--shard-size", "2500", "--seed", "3"]


def local_files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def dataset_files(files: dict[str, bytes], dataset: str) -> dict[str, bytes]:
    return {k: v for k, v in files.items() if k.startswith(f"{dataset}/")}


def smgen(*args: str):
    from smspace.cli import smgen as main

    return CliRunner().invoke(main, [str(a) for a in args], prog_name="smgen")


def smtrain(*args: str):
    from smspace.cli import smtrain as main

    return CliRunner().invoke(main, [str(a) for a in args], prog_name="smtrain")


def run_cmd(*args: str, timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
    """Run a console script of this environment as a real process."""
    cmd = [str(BIN / args[0]), *map(str, args[1:])]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **kwargs.pop("env", {})}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, **kwargs)


def short_fit(dataset: str, lake: Path | str, out: Path | str, *extra: object, timeout: float = 300):
    """`smtrain fit` of one dataset as a real process: 40 steps, evaluated at 0, 20 and 40."""
    return run_cmd("smtrain", "fit", dataset, "--lake", lake, "--out", out, "--steps", 40, "--eval-every", 20,
                   *extra, timeout=timeout)  # fmt: skip


def failed_in_one_line(result, prog: str | None = None, *, code: int | None = None, alone: bool = False) -> str:
    """The command failed (exit `code`, or any non-zero) with exactly one error line, its last,
    and no traceback; `alone`: nothing else was printed either (progress lines are not errors).
    `result` is an in-process click result (its output) or a finished process (its stderr)."""
    if hasattr(result, "exit_code"):
        status, said = result.exit_code, result.output
    else:
        status, said = result.returncode, result.stderr
    lines = [line for line in said.strip().splitlines() if line.strip()]
    assert (status == code) if code is not None else (status != 0), (status, said)
    errors = [line for line in lines if ": error: " in line]
    assert "Traceback" not in said and len(errors) == 1 and errors[0] == lines[-1], said
    assert not alone or len(lines) == 1, said
    assert prog is None or errors[0].startswith(f"{prog}: error: "), said
    return errors[0]


@pytest.fixture(scope="session")
def grid_lake(tmp_path_factory) -> Path:
    """Three modes of one grid world, 6000 transitions in 3 shards: read-only for tests."""
    lake = tmp_path_factory.mktemp("grid_lake")
    result = smgen(
        "generate",
        "--setup",
        "grid",
        "--mode",
        "all",
        "--transitions",
        6000,
        "--shard-size",
        2500,
        "--seed",
        3,
        "--lake",
        lake,
    )
    assert result.exit_code == 0, result.output
    return lake


def same_but_provenance(a: dict[str, bytes], b: dict[str, bytes]) -> str | None:
    """Two datasets' files ({name: bytes}) compared: every part byte for byte, and the manifests
    but for the note on who wrote which parts (a part found stored was written by another command,
    which the manifest says). Returns that note (None if neither has one)."""
    import json

    a, b = dict(a), dict(b)
    manifests = [json.loads(files.pop(next(k for k in files if k.endswith("manifest.json")))) for files in (a, b)]
    assert a == b, sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
    notes = [m["software"].pop("note", None) for m in manifests]
    assert manifests[0] == manifests[1]
    return notes[0] or notes[1]


# a forged shard (tests/test_integrity.py, tests/test_s3.py)
SHARD = "shard-00001.mcap"  # evaluation reads shard 0: only training meets this one


def forged(original: bytes, folder: Path) -> bytes:
    """A valid shard of the same size whose s_t1 is s_t (a predictable MEM), CRCs recomputed and
    padded into its metadata: nothing but its content tells it apart."""
    from smspace.lake.shards import Block, ShardReader, shard_bytes
    from smspace.lake.transitions import Transitions

    with ShardReader.from_bytes(original, f"{folder}/{SHARD}") as reader:
        metadata = reader.metadata()
        blocks = [
            Block(b.first_index, Transitions(**(b.transitions.columns() | {"s_t1": b.transitions.s_t})))
            for b in reader.blocks()
        ]
    short = len(original) - len(shard_bytes(blocks, metadata | {"pad": ""}))
    data = shard_bytes(blocks, metadata | {"pad": "x" * short})  # metadata is stored uncompressed
    assert len(data) == len(original)
    return data


# rerun recordings, read back with rerun's own CLI (tests/test_view.py, tests/test_walk_lake.py)
RERUN_ENV = {"CI": "true", "PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/root")}


def rerun(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / "rerun"), *map(str, args)], capture_output=True, text=True, timeout=120, env=RERUN_ENV
    )


DATA_COLUMNS = (
    "Image:buffer",
    "Scalars:scalars",
    "Points2D:positions",
    "Points3D:positions",
    "LineStrips2D:strips",
    "LineStrips3D:strips",
    "TextDocument:text",
    "InstancePoses3D:translations",
)


def rrd_rows(path) -> Counter:
    """Rows per entity holding data (not the static format or series-name rows), from `rerun rrd print`."""
    assert rerun("rrd", "verify", path).returncode == 0
    out = rerun("rrd", "print", path).stdout
    rows: Counter = Counter()
    for n, entity, columns in re.findall(r"with (\d+) rows .*? - (/\S+) - data columns: \[([^\]]*)\]", out):
        if any(c in columns.split() for c in DATA_COLUMNS):
            rows[entity] += int(n)
    return rows


def board_scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    """A run's TensorBoard scalars, read back with tensorboard's own reader."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run))
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def weights(run) -> dict:
    """A run folder's checkpointed weights (a RunDir's), as torch tensors."""
    import torch

    return torch.load(run.view.local_path / "checkpoint.pt", weights_only=True)["model"]


class StopAt:
    """A sink that interrupts training once the run folder has committed step `step`."""

    def __init__(self, step: int):
        self.step = step

    def on_evaluation(self, evaluation) -> None:
        if evaluation.step == self.step:
            raise KeyboardInterrupt

    def on_finish(self, step: int, message: str) -> None: ...
