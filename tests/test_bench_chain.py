"""scripts/bench_v3.sh, the resumable chain the v3 table is measured with: it runs a task, copies
each entry's result (bench.json, scores.json, evidence/) into the published tree and rebuilds that
task's leaderboard from the copy, so what is published verifies without the run folders."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _chain(work: Path, publish: Path, entries: str = "isomap") -> subprocess.CompletedProcess:
    env = os.environ | {"SUITE": "tiny@2", "ENTRIES": entries, "PUBLISH": str(publish)}
    return subprocess.run(
        ["bash", str(REPO / "scripts/bench_v3.sh"), str(work), "grid6"],
        env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip


def _measured(result: Path) -> list[dict]:
    rows = json.loads((result / "scores.json").read_text())["rows"]
    return [{k: v for k, v in row.items() if k != "wall_s"} for row in rows]


def test_chain_publishes_a_task_that_verifies_from_the_copy_alone(tmp_path: Path) -> None:
    work, publish = tmp_path / "work", tmp_path / "pub"
    done = _chain(work, publish)
    assert done.returncode == 0, done.stderr
    copied = publish / "grid6/results/tiny-v2/isomap/grid6"
    assert {p.name for p in copied.iterdir()} == {"bench.json", "scores.json", "evidence"}
    assert any((copied / "evidence").iterdir())
    board = json.loads((publish / "grid6/leaderboard.json").read_text())
    assert len(board["results"]) == 1  # the copy verified: a result that fails is left out
    assert "start grid6" in (work / "chain.log").read_text() and "end grid6 rc=0" in (work / "chain.log").read_text()

    # the same command continues and publishes the same scores (isomap is fitted again in a second
    # session: its evidence, hashed in each row, is the same bytes)
    first = _measured(copied)
    again = _chain(work, publish)
    assert again.returncode == 0, again.stderr
    assert _measured(copied) == first
    assert (work / "chain.log").read_text().count("end grid6 rc=0") == 2


def test_chain_on_a_new_machine_runs_only_the_entries_not_published(tmp_path: Path) -> None:
    """WORK lost with a machine, the published tree kept (as the checkout is): the published entry
    is not trained again (its bench.json keeps its one session), the missing one runs, and the
    leaderboard is rebuilt from both."""
    publish = tmp_path / "pub"
    assert _chain(tmp_path / "old", publish).returncode == 0
    isomap = publish / "grid6/results/tiny-v2/isomap/grid6"
    before = (isomap / "bench.json").read_bytes(), (isomap / "scores.json").read_bytes()

    done = _chain(tmp_path / "new", publish, "isomap random-encoder")
    assert done.returncode == 0, done.stderr
    assert ((isomap / "bench.json").read_bytes(), (isomap / "scores.json").read_bytes()) == before
    assert not (tmp_path / "new/runs/tiny-v2/isomap").exists()
    assert (publish / "grid6/results/tiny-v2/random-encoder/grid6/scores.json").is_file()
    board = json.loads((publish / "grid6/leaderboard.json").read_text())
    assert len(board["results"]) == 2
    log = (tmp_path / "new/chain.log").read_text()
    assert "start grid6: random-encoder" in log and "end grid6 rc=0" in log

    # everything published: nothing runs, the leaderboard is still rebuilt
    (publish / "grid6/leaderboard.json").unlink()
    assert _chain(tmp_path / "newer", publish, "isomap random-encoder").returncode == 0
    assert "every entry published" in (tmp_path / "newer/chain.log").read_text()
    assert len(json.loads((publish / "grid6/leaderboard.json").read_text())["results"]) == 2
