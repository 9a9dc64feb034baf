"""Bad input: one clear line, exit 2, nothing written; broken shards are named."""

from __future__ import annotations

import json
import shutil
from functools import partial
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from smspace import schemas
from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset

from .conftest import failed_in_one_line, smgen

one_error_line = partial(failed_in_one_line, prog="smgen", code=2, alone=True)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--setup", "cube", "--mode", "MM"], "'cube' is not one of 'grid'"),
        (["--setup", "grid", "--mode", "XM"], "unknown mode 'XM'"),
        (["--setup", "grid", "--mode", "MM", "--transitions", "0"], "--transitions must be positive"),
        (["--setup", "grid", "--mode", "MM", "--transitions", "-5"], "--transitions must be positive"),
        (["--setup", "grid", "--mode", "MM", "--shard-size", "0"], "--shard-size must be positive"),
    ],
)
def test_bad_generate_flags(tmp_path, args, needle):
    lake = tmp_path / "lake"
    line = one_error_line(smgen("generate", *args, "--lake", lake))
    assert needle in line
    assert not lake.exists() or not any(lake.iterdir())


def test_wrong_flag_is_a_usage_error(tmp_path):
    result = smgen("generate", "--setup", "grid", "--mode", "MM", "--colour", "red")
    assert result.exit_code == 2 and "No such option" in result.output


def test_lake_path_that_is_a_file(tmp_path):
    f = tmp_path / "lake.txt"
    f.write_text("not a lake")
    line = one_error_line(smgen("generate", "--setup", "grid", "--mode", "MM", "--lake", f))
    assert str(f) in line and "is a file" in line
    assert f.read_text() == "not a lake"


def test_unwritable_lake_folder():
    line = one_error_line(smgen("generate", "--setup", "grid", "--mode", "MM", "--lake", "/sys/smspace-lake"))
    assert "/sys/smspace-lake" in line


def test_unknown_dataset_id(grid_lake):
    line = one_error_line(smgen("info", "--lake", grid_lake, "grid-seed99-MM"))
    assert "grid-seed99-MM" in line
    assert one_error_line(smgen("validate", "--lake", grid_lake, "nope"))


@pytest.fixture
def lake_copy(grid_lake, tmp_path) -> Path:
    dst = tmp_path / "lake"
    shutil.copytree(grid_lake, dst)
    return dst


def test_validate_names_a_truncated_shard(lake_copy):
    shard = lake_copy / "grid-seed3-MM" / "shard-00001.mcap"
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    result = smgen("validate", "--lake", lake_copy, "grid-seed3-MM", "grid-seed3-MME")
    assert result.exit_code == 1
    bad = [line for line in result.output.splitlines() if "shard-00001.mcap" in line]
    assert bad and all(line.startswith("grid-seed3-MM/shard-00001.mcap") for line in bad)
    assert "grid-seed3-MME: ok" in result.output


def test_validate_names_a_bit_flipped_shard(lake_copy):
    shard = lake_copy / "grid-seed3-MEM" / "shard-00002.mcap"
    data = bytearray(shard.read_bytes())
    data[len(data) // 3] ^= 0x10
    shard.write_bytes(bytes(data))
    result = smgen("validate", "--lake", lake_copy, "grid-seed3-MEM")
    assert result.exit_code == 1
    assert "grid-seed3-MEM/shard-00002.mcap: sha256 differs" in result.output
    assert "CRC" in result.output or "corrupt" in result.output  # the MCAP chunk CRC catches it too
    with pytest.raises(SmspaceError, match="shard-00002"):
        Dataset.open("grid-seed3-MEM", lake_copy).read_all()


def test_validate_catches_a_broken_mode_invariant(lake_copy):
    """An MME dataset whose shard really holds MEM transitions is flagged, not trusted."""
    mme, mem = lake_copy / "grid-seed3-MME", lake_copy / "grid-seed3-MEM"
    shutil.copy(mem / "shard-00000.mcap", mme / "shard-00000.mcap")
    result = smgen("validate", "--lake", lake_copy, "grid-seed3-MME")
    assert result.exit_code == 1
    assert "grid-seed3-MME/shard-00000.mcap: MME shift_t != shift_t1" in result.output


def write_foreign_shard(path: Path, schema_name: str) -> None:
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start()
        sid = w.register_schema(
            schema_name, "protobuf", build_file_descriptor_set(schemas.TransitionBatch).SerializeToString()
        )
        cid = w.register_channel("/transitions", "protobuf", sid)
        w.add_message(cid, log_time=0, publish_time=0, data=b"")
        w.finish()


def test_shard_of_another_schema_version(lake_copy):
    shard = lake_copy / "grid-seed3-MM" / "shard-00000.mcap"
    write_foreign_shard(shard, "smspace.v3.TransitionBatch")
    result = smgen("validate", "--lake", lake_copy, "grid-seed3-MM")
    assert result.exit_code == 1
    assert "grid-seed3-MM/shard-00000.mcap" in result.output and "smspace.v3.TransitionBatch" in result.output
    with pytest.raises(SmspaceError, match=r"shard-00000.mcap is not the file dataset grid-seed3-MM records"):
        Dataset.open("grid-seed3-MM", lake_copy).read_all()  # readers refuse bytes the manifest does not record
    from smspace.lake.shards import ShardReader
    from smspace.lake.store import open_store

    with pytest.raises(SmspaceError, match=r"shard-00000.mcap has schema smspace.v3"):
        ShardReader(open_store(shard.parent), shard.name)  # and a shard opened on its own says what it is


def test_manifest_of_another_schema_version(lake_copy):
    path = lake_copy / "grid-seed3-MM" / "manifest.json"
    raw = json.loads(path.read_text())
    raw["schema_version"] = 3
    path.write_text(json.dumps(raw))
    line = one_error_line(smgen("info", "--lake", lake_copy, "grid-seed3-MM"))
    assert "schema version 3" in line


def test_full_disk_leaves_no_partial_shard(tmp_path, monkeypatch):
    """ENOSPC mid-write: a clear error naming the file, and no half-written shard."""
    import builtins
    import io

    import smspace.common.atomic as atomic

    class FillsUp(io.FileIO):
        def write(self, data):  # half the shard reaches the disk, then the disk is full
            super().write(bytes(data)[: len(data) // 2])
            raise OSError(28, "No space left on device")

    def full_disk_open(path, mode="r", *args, **kwargs):
        if "shard-00000" in str(path) and "w" in mode:
            return FillsUp(path, "w")
        return builtins.open(path, mode, *args, **kwargs)

    monkeypatch.setattr(atomic, "open", full_disk_open, raising=False)
    line = one_error_line(
        smgen("generate", "--setup", "grid", "--mode", "MM", "--transitions", 5000, "--workers", 1, "--lake", tmp_path)
    )
    assert "No space left on device" in line and "shard-00000.mcap" in line
    folder = tmp_path / "grid-seed0-MM"
    assert not list(folder.glob("shard-*")) and not (folder / "manifest.json").exists()


def test_a_mistyped_lake_is_not_an_empty_listing(tmp_path):
    line = one_error_line(smgen("ls", "--lake", tmp_path / "no-such-lake"))
    assert "no lake at" in line and "no-such-lake" in line
    assert not (tmp_path / "no-such-lake").exists()


def test_ctrl_c_during_generation_says_how_to_complete_it(tmp_path):
    import signal
    import subprocess
    import time

    from .conftest import BIN

    lake = tmp_path / "lake"
    args = ["generate", "--setup", "grid", "--mode", "MM", "--transitions", "3000000", "--workers", "1"]
    proc = subprocess.Popen(
        [str(BIN / "smgen"), *args, "--lake", str(lake)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a terminal
    )
    deadline = time.time() + 600
    while time.time() < deadline and not list(lake.glob("grid-seed0-MM/shard-*.mcap")):
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == (
        "interrupted; the parts already stored are kept: the same command completes the datasets"
    )
    assert not (lake / "grid-seed0-MM" / "manifest.json").exists()


def test_generation_flags_are_declared_once_for_smgen_and_sweep():
    from smspace.datagen.cli import generate
    from smspace.study.cli import sweep

    def param(command, dest: str):
        (found,) = [p for p in command.params if p.name == dest]
        return found

    shared = {"setup_name": "setup_name", "worlds": "worlds", "transitions": "transitions", "seed": "first_world",
              "workers": "gen_workers"}  # fmt: skip
    for mine, theirs in shared.items():
        assert repr(param(generate, mine).type) == repr(param(sweep, theirs).type), mine
        if mine != "seed":  # sweep says what its first seed also is: the runs' seed
            assert param(generate, mine).help == param(sweep, theirs).help, mine


TOP_SEED = str(2**63 - 1)


@pytest.mark.parametrize(
    ("gen_args", "sweep_args", "needle"),
    [
        (["--worlds", "0"], ["--worlds", "0"], "--worlds"),
        (["--seed", "-1"], ["--seed", "-1"], "--seed"),
        (["--workers", "1025"], ["--gen-workers", "1025"], "workers"),
        (["--seed", TOP_SEED, "--worlds", "2"], ["--seed", TOP_SEED, "--worlds", "2"], "largest world seed"),
        (["--transitions", "0"], ["--transitions", "0"], "--transitions must be positive"),
    ],
)
def test_a_generation_bound_holds_in_smgen_and_in_sweep(tmp_path, gen_args, sweep_args, needle):
    from .conftest import smtrain

    lake, out = tmp_path / "lake", tmp_path / "runs"
    for result in (
        smgen("generate", "--setup", "grid", "--mode", "MM", *gen_args, "--lake", lake),
        smtrain("sweep", "--setup", "grid", "--modes", "MM", *sweep_args, "--lake", lake, "--out", out),
    ):
        assert result.exit_code == 2, result.output
        assert needle in result.output, result.output
    assert not lake.exists() or not any(lake.iterdir())
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("transitions", 0, "must be positive, got 0"),
        ("transitions", 2**41, f"{2**41} is more than a dataset may hold ({2**40})"),
        ("worlds", 0, "must be positive, got 0"),
        ("worlds", 100_001, "100001 is more than one command plans"),
        ("seed", -1, "must be at least 0, got -1"),
        ("transitions", "many", "must be an integer, got 'many'"),
    ],
)
def test_a_bad_dataset_number_is_refused_in_the_same_words_by_a_flag_a_study_file_and_the_api(
    tmp_path, key, value, said
):
    """lake/bounds.py: one declaration of each number a dataset request holds, one wording."""
    import smspace

    lake = tmp_path / "lake"
    flag = smgen("generate", "--setup", "grid", "--mode", "MM", f"--{key}", str(value), "--lake", str(lake))
    assert f"smgen: error: --{key} {said}" in one_error_line(flag)
    study = tmp_path / "s.toml"
    study.write_text(f'[study]\nsetup = "grid"\nmodes = ["MM"]\n{key} = {json.dumps(value)}\n')
    with pytest.raises(SmspaceError, match=f"study.{key}: {said[:12]}"):
        smspace.dry_run(study, out=tmp_path / "runs", lake=lake)
    with pytest.raises(SmspaceError, match=f"^{key} {said[:12]}"):
        smspace.generate("grid", "MM", lake=lake, **{key: value})
    assert not lake.exists() or not any(lake.glob("grid-*"))
