"""Our shards are plain MCAP with embedded schemas: other readers decode them without our code."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from smspace.lake.dataset import Dataset

from .conftest import BIN


def rerun_check(path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / "rerun"), "mcap", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        env={"CI": "true", "PATH": "/usr/bin:/bin"},
    )


def test_rerun_mcap_check_accepts_our_shards_and_rejects_a_corrupt_one(grid_lake, tmp_path):
    folder = grid_lake / "grid-seed3-MEM"
    for path in [*sorted(folder.glob("shard-*.mcap")), folder / "regular.mcap"]:
        result = rerun_check(path)
        assert result.returncode == 0, result.stdout + result.stderr
    broken = tmp_path / "broken.mcap"
    shutil.copy(folder / "shard-00000.mcap", broken)
    data = bytearray(broken.read_bytes())
    data[len(data) // 2] ^= 0xFF
    broken.write_bytes(bytes(data))
    assert rerun_check(broken).returncode == 1


def test_generic_protobuf_decoder_reads_the_embedded_schema(grid_lake):
    """mcap-protobuf-support builds the message class from the file's FileDescriptorSet alone."""
    ds = Dataset.open("grid-seed3-MME", grid_lake)
    ours = ds.read_all()
    with open(ds.store.local_path / ds.manifest.shards[0]["file"], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()], validate_crcs=True)
        schema, _, _, msg = next(iter(reader.iter_decoded_messages(log_time_order=False)))
    assert schema.name == "smspace.v1.TransitionBatch"
    n = msg.count
    np.testing.assert_array_equal(np.array(msg.m_t1, np.float32).reshape(n, 3), ours.m_t1[:n])
    np.testing.assert_array_equal(np.array(msg.s_t.float32.values, np.float32).reshape(n, 4), ours.s_t[:n])
    np.testing.assert_array_equal(np.array(msg.privileged.shift_t, np.float32).reshape(n, 2), ours.shift_t[:n])
