"""rerun replay (smgen view, smtrain view) and the Foxglove / Parquet exports, checked headlessly."""

from __future__ import annotations

import os
import signal
import subprocess
import time
import urllib.request

import numpy as np
import psutil
import pytest

from smspace.datagen.export import read_parquet_transitions
from smspace.lake.dataset import Dataset

from .conftest import BIN, RERUN_ENV, SAMPLES, rerun, rrd_rows, run_cmd, smgen
from .servers import alive, children_of, free_port


def rrd_components(path) -> str:
    result = rerun("rrd", "stats", path)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_smgen_view_grid_dataset(tmp_path):
    out = tmp_path / "grid.rrd"
    result = smgen("view", "grid-seed0-MME", "--lake", SAMPLES, "--save", out, "--limit", 3000)
    assert result.exit_code == 0, result.output
    rows = rrd_rows(out)
    for entity in ("/sensor/s_t", "/sensor/s_t1", "/motor/m_t", "/motor/m_t1", "/ego/p_t", "/ego/p_t1", "/shift/t"):
        assert rows[entity] == 3000, entity
    assert rows["/dataset"] == 1 and rows["/ego/reachable"] == 1
    stats = rrd_components(out)
    assert "transition:" in stats and "Scalars:scalars" in stats and "TextDocument:text" in stats


def test_smgen_view_arm_dataset_has_images_and_a_room_map(tmp_path):
    out = tmp_path / "arm.rrd"
    result = smgen("view", "arm-seed0-MEM", "--lake", SAMPLES, "--save", out)
    assert result.exit_code == 0, result.output
    rows = rrd_rows(out)
    assert rows["/sensor/s_t"] == rows["/sensor/s_t1"] == rows["/map/camera_t"] == 1024
    assert rows["/map/room"] == 1
    stats = rrd_components(out)
    assert "Image:buffer" in stats and "Points2D:positions" in stats


def test_smtrain_view_run(tmp_path):
    from click.testing import CliRunner

    from smspace.cli import smtrain as smtrain_main

    run = tmp_path / "run"
    r = CliRunner().invoke(
        smtrain_main,
        ["fit", "arm-seed0-MM", "--lake", str(SAMPLES), "--steps", "40", "--eval-every", "20", "--out", str(run)],
    )
    assert r.exit_code == 0, r.output
    out = tmp_path / "run.rrd"
    r = CliRunner().invoke(smtrain_main, ["view", str(run), "--save", str(out)])
    assert r.exit_code == 0, r.output
    rows = rrd_rows(out)
    assert rows["/h"] == 3 and rows["/projection/h_hat"] == 3 and rows["/projection/lines"] == 3
    assert rows["/curves/d_metric/value"] == 3 and rows["/predictions/predicted"] == 3
    stats = rrd_components(out)
    assert "step:" in stats and "Points3D:positions" in stats and "LineStrips2D:strips" in stats


def test_foxglove_export_opens_in_rerun_as_images(tmp_path):
    out = tmp_path / "arm.mcap"
    result = smgen("export", "arm-seed0-MME", "--lake", SAMPLES, "--format", "foxglove", "--out", out, "--limit", 300)
    assert result.exit_code == 0, result.output
    assert rerun("mcap", "check", out).returncode == 0
    rrd = tmp_path / "arm.rrd"
    assert rerun("mcap", "convert", out, "-o", rrd).returncode == 0
    rows = rrd_rows(rrd)
    assert rows["/s_t"] == rows["/s_t1"] == 300
    stats = rrd_components(rrd)
    assert "Image:buffer" in stats and "InstancePoses3D" in stats


def test_parquet_export_reads_back_equal(tmp_path):
    for ds_id in ("arm-seed0-MEM", "grid-seed0-MM"):
        out = tmp_path / f"{ds_id}.parquet"
        assert smgen("export", ds_id, "--lake", SAMPLES, "--format", "parquet", "--out", out).exit_code == 0
        index, got, manifest = read_parquet_transitions(out)
        src = Dataset.open(ds_id, SAMPLES).read_all()
        np.testing.assert_array_equal(index, np.arange(len(src)))
        for name in src.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(got, name), getattr(src, name), err_msg=name)
        assert manifest["dataset_id"] == ds_id


def test_export_bad_input(tmp_path):
    r = smgen("export", "arm-seed0-MEM", "--lake", SAMPLES, "--format", "csv", "--out", tmp_path / "x")
    assert r.exit_code == 2
    r = smgen("export", "arm-seed0-MEM", "--lake", SAMPLES, "--format", "parquet", "--out", tmp_path)
    assert r.exit_code == 2 and "is a folder" in r.output


def listeners(port: int) -> set[str]:
    return {c.laddr.ip for c in psutil.net_connections("tcp") if c.status == "LISTEN" and c.laddr.port == port}


@pytest.mark.slow
def test_web_viewer_binds_loopback_and_ctrl_c_stops_everything():
    web, grpc = free_port(), free_port()
    proc = subprocess.Popen(
        [
            str(BIN / "smgen"),
            "view",
            "grid-seed0-MM",
            "--lake",
            str(SAMPLES),
            "--limit",
            "500",
            "--web",
            "--web-port",
            str(web),
            "--grpc-port",
            str(grpc),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **RERUN_ENV},
        # as from a terminal: a suite run as a background job (`pytest &`) passes SIGINT down ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline, body = time.time() + 60, None
        while time.time() < deadline and body is None:
            try:
                body = urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=2).read()
            except OSError:
                time.sleep(0.2)
        assert body is not None and b"<html" in body.lower()
        assert listeners(web) == {"127.0.0.1"} and listeners(grpc) == {"127.0.0.1"}
        children = psutil.Process(proc.pid).children(recursive=True)
        viewer_pids = {p.pid for p in children} | children_of(proc.pid)
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=60)  # communicate: a full stderr pipe must not stall it
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"smgen view ignored Ctrl-C for 60 s; its stderr: {proc.communicate()[1][-2000:]}")
        assert "http://127.0.0.1:" in err
        time.sleep(0.5)
        assert not listeners(web) and not listeners(grpc)
        assert not alive(viewer_pids)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_view_without_a_display_writes_the_recording_and_says_where(tmp_path, monkeypatch):
    """No $DISPLAY: a viewer window cannot open (it took ~13 s, then gRPC logs and a traceback);
    the recording is written to the current folder instead, under a name not yet taken."""
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    (tmp_path / "grid-seed0-MM.rrd").write_bytes(b"someone's file")
    done = run_cmd("smgen", "view", "grid-seed0-MM", "--lake", SAMPLES, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    written = tmp_path / "grid-seed0-MM-1.rrd"
    assert f"the recording goes to {written}" in done.stderr and "Traceback" not in done.stderr
    assert rrd_rows(written) and (tmp_path / "grid-seed0-MM.rrd").read_bytes() == b"someone's file"
