"""Walk datasets end to end (issue 44): `smgen generate --exploration walk` for the grid and the
arm, read back as episodes of schema version 2, validated (and a broken episode named), trained
on and viewed; transitions datasets still read as transitions, with the hashes they had."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from smspace import schemas
from smspace.lake.dataset import Dataset
from smspace.lake.episodes import episode_problem
from smspace.lake.shards import Block, ShardReader, shard_bytes
from smspace.lake.transitions import Transitions

from .conftest import failed_in_one_line, local_files, rrd_rows, short_fit, smgen

WALK = ["--exploration", "walk", "--walk-length", "40", "--transitions", "4000", "--shard-size", "2000"]


@pytest.fixture(scope="module")
def walk_lake(tmp_path_factory) -> Path:
    lake = tmp_path_factory.mktemp("walk_lake")
    result = smgen("generate", "--setup", "grid", "--mode", "all", "--seed", 2, "--lake", lake, *WALK)
    assert result.exit_code == 0, result.output
    return lake


@pytest.mark.parametrize("mode", ["MM", "MME", "MEM"])
def test_a_grid_walk_reads_back_as_whole_episodes(walk_lake, mode):
    ds = Dataset.open(f"grid-seed2-{mode}-walk", walk_lake)
    assert ds.manifest.schema_version == schemas.WALKS_VERSION
    assert ds.manifest.config["exploration"] == {"kind": "walk", "length": 40, "step": 1.0}
    t = ds.read_all()
    episode, step = ds.episodes()
    assert len(t) == 4000 and episode.tolist() == np.repeat(np.arange(100), 40).tolist()
    assert step.tolist() == np.tile(np.arange(40), 100).tolist()
    assert episode_problem(t, episode, step, mode) is None
    # the grid walks on its lattice: each motor moves by at most one level per step
    levels = np.unique(t.m_t)
    moved = np.abs(np.searchsorted(levels, t.m_t1) - np.searchsorted(levels, t.m_t))
    assert moved.max() == 1 and (moved == 0).any()
    starts = step == 0
    if mode == "MME":  # the environment moves between episodes only
        assert len(np.unique(t.shift_t[starts], axis=0)) > 1
        assert np.array_equal(t.shift_t, t.shift_t1)
    assert smgen("validate", f"grid-seed2-{mode}-walk", "--lake", walk_lake).exit_code == 0
    info = json.loads(smgen("info", f"grid-seed2-{mode}-walk", "--lake", walk_lake, "--json").output)
    assert info["exploration"] == "walk: episodes of 40 steps of 1" and info["schema_version"] == 2


def test_walks_are_reproducible_and_leave_transitions_as_they_were(walk_lake, tmp_path):
    again = tmp_path / "again"
    assert smgen("generate", "--setup", "grid", "--mode", "MME", "--seed", 2, "--lake", again, *WALK).exit_code == 0
    mine = {k: v for k, v in local_files(again).items() if k.startswith("grid-seed2-MME-walk/") and "manifest" not in k}
    theirs = {k: v for k, v in local_files(walk_lake).items() if k in mine}
    assert mine and mine == theirs
    # the same world's transitions beside it: schema version 1, no exploration in the config
    assert smgen("generate", "--setup", "grid", "--mode", "MME", "--seed", 2, "--lake", again,
                 "--transitions", "4000", "--shard-size", "2000").exit_code == 0  # fmt: skip
    plain = Dataset.open("grid-seed2-MME", again)
    assert plain.manifest.schema_version == schemas.TRANSITIONS_VERSION and plain.episodes() is None
    assert "exploration" not in plain.manifest.config
    with ShardReader(plain.store, "shard-00000.mcap") as reader:
        assert all(b.version == schemas.TRANSITIONS_VERSION for b in reader.blocks())


def test_an_arm_walk_generates_and_validates(tmp_path):
    args = ["--exploration", "walk", "--walk-length", "10", "--transitions", "60", "--shard-size", "30"]
    result = smgen("generate", "--setup", "arm", "--mode", "MME", "--lake", tmp_path, *args)
    assert result.exit_code == 0, result.output
    ds = Dataset.open("arm-seed0-MME-walk", tmp_path)
    t = ds.read_all()
    episode, step = ds.episodes()
    assert t.s_t.dtype == np.uint8 and episode_problem(t, episode, step, "MME") is None
    assert np.abs(t.m_t1 - t.m_t).max() < 1.0  # a walk of 0.1 per step, not a teleport
    assert smgen("validate", "arm-seed0-MME-walk", "--lake", tmp_path).exit_code == 0


def _rewrite_shard(folder: Path, name: str, change) -> None:
    """A shard whose blocks `change` altered, stored with a manifest that vouches for it: only its
    content can tell it apart (a walk written by another tool, not damaged in transit)."""
    path = folder / name
    with ShardReader.from_bytes(path.read_bytes(), str(path)) as reader:
        metadata, blocks = reader.metadata(), [change(b) for b in reader.blocks()]
    data = shard_bytes(blocks, metadata)
    path.write_bytes(data)
    manifest = json.loads((folder / "manifest.json").read_text())
    for entry in manifest["shards"]:
        if entry["file"] == name:
            entry |= {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(),
                      "md5": hashlib.md5(data, usedforsecurity=False).hexdigest()}  # fmt: skip
    (folder / "manifest.json").write_text(json.dumps(manifest))


def test_validate_names_a_broken_episode(walk_lake, tmp_path):
    import shutil

    folder = tmp_path / "grid-seed2-MM-walk"
    shutil.copytree(walk_lake / "grid-seed2-MM-walk", folder)

    def teleport(block: Block) -> Block:
        columns = block.transitions.columns()
        m_t = columns["m_t"].copy()
        m_t[45] = -m_t[45]  # row 45 of the block no longer starts where row 44 ended
        return Block(block.first_index, Transitions(**(columns | {"m_t": m_t})), block.episode, block.step)

    _rewrite_shard(folder, "shard-00001.mcap", teleport)
    result = smgen("validate", folder)
    assert result.exit_code == 1
    assert "shard-00001.mcap: transition 2045: m_t is not the m_t1 of the step before (episode 51)" in result.output


def test_training_streams_walks(walk_lake, tmp_path):
    out = tmp_path / "run"
    result = short_fit("grid-seed2-MME-walk", walk_lake, out, "--batch-size", 64)
    assert result.returncode == 0, result.stderr
    final = json.loads(result.stdout.strip().splitlines()[-1])
    assert final["step"] == 40 and np.isfinite(final["d_metric"])


def test_view_draws_the_episode_as_a_path(walk_lake, tmp_path):
    out = tmp_path / "walk.rrd"
    result = smgen("view", "grid-seed2-MME-walk", "--lake", walk_lake, "--save", out, "--limit", 500)
    assert result.exit_code == 0, result.output
    rows = rrd_rows(out)
    assert rows["/ego/path"] == rows["/motor_path/path"] == rows["/ego/p_t"] == 500


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--walk-length", "64"], "must fill the shards"),
        (["--walk-step", "1.5"], "a whole number of levels"),
        (["--walk-length", "0"], "--walk-length"),
    ],
)
def test_bad_walk_requests_are_refused_before_anything_is_written(tmp_path, args, named):
    lake = tmp_path / "lake"
    base = ["--exploration", "walk", "--transitions", "4000", "--shard-size", "2000"]
    result = smgen("generate", "--setup", "grid", "--mode", "MM", "--lake", lake, *base, *args)
    assert named in failed_in_one_line(result, "smgen")
    assert not lake.exists() or not any(p.name.startswith("grid-") for p in lake.iterdir())


def _windows_of(batches) -> np.ndarray:
    """Each sample of step-window batches as one row: per step, m_t, s_t, m_t1, s_t1."""
    return np.vstack([torch.cat(b, dim=2).reshape(len(b.m_t), -1).numpy() for b in batches])


def test_the_loader_streams_windows_of_consecutive_steps_once_each_and_resumes_exactly(walk_lake):
    from smspace.lake.normalise import normalisers
    from smspace.train.loader import TransitionStream, step_windows

    ds = Dataset.open("grid-seed2-MME-walk", walk_lake)
    stream = TransitionStream(ds, batch_size=32, seed=4, epochs=1, steps=5)
    batches = list(stream)
    assert batches[0].m_t.shape == (32, 5, 3) and batches[0].s_t1.shape == (32, 5, 4)
    for b in batches:  # consecutive steps: each one starts where the step before it ended
        np.testing.assert_array_equal(b.m_t[:, 1:], b.m_t1[:, :-1])
        np.testing.assert_array_equal(b.s_t[:, 1:], b.s_t1[:, :-1])
    got = _windows_of(batches)
    t = ds.read_all()
    m_norm, s_norm = normalisers(ds.manifest)
    rows = np.hstack([m_norm(t.m_t), s_norm(t.s_t), m_norm(t.m_t1), s_norm(t.s_t1)])
    expected = step_windows(rows, 40, 5)
    assert len(got) == len(expected) == 100 * (40 - 5 + 1)
    order = lambda x: x[np.lexsort(x.T[::-1])]  # noqa: E731
    np.testing.assert_array_equal(order(got), order(expected))  # every window exactly once
    # resumed after 17 batches, the stream goes on exactly as it would have
    endless = lambda: TransitionStream(ds, batch_size=32, seed=4, steps=5)  # noqa: E731
    full = _windows_of(b for _, b in zip(range(60), endless(), strict=False))
    first = endless()
    head = _windows_of(b for _, b in zip(range(17), first, strict=False))
    resumed = endless()
    resumed.load_state_dict(first.state_dict())
    tail = _windows_of(b for _, b in zip(range(43), resumed, strict=False))
    np.testing.assert_array_equal(np.vstack([head, tail]), full)
    with pytest.raises(ValueError, match="5-step windows resumed with 1"):
        TransitionStream(ds, batch_size=32, seed=4).load_state_dict(first.state_dict())


def test_windows_need_walks_that_fit_them(walk_lake, tmp_path):
    from smspace.train.loader import TransitionStream

    with pytest.raises(ValueError, match=r"do not fit in .* episodes of 40"):
        TransitionStream(Dataset.open("grid-seed2-MM-walk", walk_lake), steps=41)
    assert (
        smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 2000, "--lake", tmp_path).exit_code == 0
    )
    with pytest.raises(ValueError, match="independent transitions: windows of 3 steps need walks"):
        TransitionStream(Dataset.open("grid-seed0-MM", tmp_path), steps=3)
