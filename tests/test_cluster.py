"""Generation beyond one process: a job array's ranks then `finalize`, and Ray on a two-node local
cluster (every node bound to 127.0.0.1, checked with `ss`, every Ray process gone afterwards)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import psutil
import pytest

from tests.conftest import BIN, dataset_files, local_files, same_but_provenance, smgen
from tests.servers import alive, assert_loopback_only, processes_marked, tree

GRID = ["--setup", "grid", "--transitions", "6000", "--shard-size", "2500", "--seed", "3"]


def test_ranks_then_finalize_give_the_bytes_of_one_command(grid_lake, tmp_path):
    lake = tmp_path / "lake"
    for rank in range(3):
        result = smgen("generate", *GRID, "--mode", "MEM", "--rank", rank, "--world-size", 3, "--lake", lake)
        assert result.exit_code == 0, result.output
        assert "smgen finalize grid-seed3-MEM" in result.output
    folder = lake / "grid-seed3-MEM"
    assert sorted(p.name for p in folder.glob("shard-*")) == [f"shard-0000{i}.mcap" for i in range(3)]
    assert not (folder / "manifest.json").exists()
    assert smgen("ls", "--lake", lake, "--json").output == ""  # nothing complete before the commit

    done = smgen("finalize", "grid-seed3-MEM", "--lake", lake)
    assert done.exit_code == 0 and "written" in done.output, done.output
    note = same_but_provenance(
        dataset_files(local_files(lake), "grid-seed3-MEM"), dataset_files(local_files(grid_lake), "grid-seed3-MEM")
    )
    assert note.startswith("every part was found stored")  # written by the ranks, not by finalize
    again = smgen("finalize", "grid-seed3-MEM", "--lake", lake)
    assert again.exit_code == 0 and "exists" in again.output


def test_finalize_with_a_rank_missing_names_the_shard_and_commits_nothing(tmp_path):
    lake = tmp_path / "lake"
    for rank in (0, 1):
        assert (
            smgen("generate", *GRID, "--mode", "MM", "--rank", rank, "--world-size", 3, "--lake", lake).exit_code == 0
        )
    result = smgen("finalize", "grid-seed3-MM", "--lake", lake)
    assert result.exit_code == 2
    assert "shard-00002.mcap is not written yet (its rank is still running, or failed)" in result.output
    assert result.output.count("\n") == 1
    assert not (lake / "grid-seed3-MM" / "manifest.json").exists()
    # a damaged part is refused the same way
    (lake / "grid-seed3-MM" / "shard-00002.mcap").write_bytes(b"not an mcap file")
    result = smgen("finalize", "grid-seed3-MM", "--lake", lake)
    assert result.exit_code == 2 and "shard-00002.mcap is invalid" in result.output


def test_rank_flags_are_checked(tmp_path):
    bad = smgen("generate", *GRID, "--mode", "MM", "--rank", 3, "--world-size", 3, "--lake", tmp_path)
    assert bad.exit_code == 2 and "--rank 3" in bad.output
    bad = smgen("generate", *GRID, "--mode", "MM", "--rank", 0, "--world-size", 2, "--overwrite", "--lake", tmp_path)
    assert bad.exit_code == 2 and "--overwrite" in bad.output
    assert not any(tmp_path.iterdir())


@pytest.fixture()
def ray_cluster(monkeypatch, tmp_path):
    """Two Ray nodes on this machine, one CPU each, every process bound to 127.0.0.1."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    for key, value in {
        "RAY_AUTH_MODE": "disabled",
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_DISABLE_DOCKER_CPU_WARNING": "1",
    }.items():
        monkeypatch.setenv(key, value)
    node = {"num_cpus": 1, "node_ip_address": "127.0.0.1", "include_dashboard": False}
    before = tree(os.getpid())
    cluster = Cluster(initialize_head=True, head_node_args=node)
    try:
        cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
        cluster.wait_for_nodes()
        started = tree(os.getpid()) - before
        yield cluster, started
    finally:
        cluster.shutdown()
    started_all = started | (tree(os.getpid()) - before)
    leftovers = {pid for pid in started_all if tree(pid)}
    assert not leftovers, f"Ray processes still alive: {leftovers}"


@pytest.mark.slow
def test_ray_executor_on_two_nodes_gives_the_bytes_of_local(ray_cluster, grid_lake, tmp_path):
    cluster, _ = ray_cluster
    lake = tmp_path / "lake"
    env = {**os.environ, "RAY_ADDRESS": cluster.address}
    proc = subprocess.run(
        [str(BIN / "smgen"), "generate", *GRID, "--mode", "all", "--executor", "ray", "--lake", str(lake)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("written") == 3
    assert local_files(lake).keys() == local_files(grid_lake).keys()
    for mode in ("MEM", "MM", "MME"):
        ds = f"grid-seed3-{mode}"
        assert dataset_files(local_files(lake), ds) == dataset_files(local_files(grid_lake), ds)
    # both nodes and all their workers listened on 127.0.0.1 only
    assert assert_loopback_only(tree(os.getpid())) >= 2


@pytest.mark.slow
def test_ray_runs_the_arm_preflight_on_a_worker_not_the_driver(ray_cluster, tmp_path):
    """A driver without Vulkan still generates the arm: SAPIEN runs only on the workers."""
    cluster, _ = ray_cluster
    args = ["--setup", "arm", "--mode", "MM", "--transitions", "256", "--shard-size", "128", "--seed", "2"]
    no_vulkan = {**os.environ, "RAY_ADDRESS": cluster.address, "VK_ICD_FILENAMES": str(tmp_path / "none.json")}
    ray_run = subprocess.run(
        [str(BIN / "smgen"), "generate", *args, "--executor", "ray", "--lake", str(tmp_path / "ray")],
        capture_output=True,
        text=True,
        env=no_vulkan,
        timeout=600,
    )
    assert ray_run.returncode == 0, ray_run.stderr
    local = smgen("generate", *args, "--lake", tmp_path / "local")
    assert local.exit_code == 0, local.output
    got = dataset_files(local_files(tmp_path / "ray"), "arm-seed2-MM")
    assert got == dataset_files(local_files(tmp_path / "local"), "arm-seed2-MM") and len(got) == 4
    # and without Ray the same driver refuses in one line before writing anything
    refused = subprocess.run(
        [str(BIN / "smgen"), "generate", *args, "--lake", str(tmp_path / "refused")],
        capture_output=True,
        text=True,
        env=no_vulkan,
        timeout=300,
    )
    assert refused.returncode == 2 and not (tmp_path / "refused").exists()


@pytest.mark.slow
def test_ray_executor_without_a_cluster_starts_and_stops_a_local_ray(grid_lake, tmp_path):
    """No $RAY_ADDRESS: smgen starts a Ray of its own on this machine, every process of which
    (gcs_server, raylet, agents, workers: found by the mark in their environment, wherever they sit
    in the process tree) listens on 127.0.0.1 only, and stops every process it started."""
    pytest.importorskip("ray")
    marker = f"{os.getpid()}-{tmp_path.name}"
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER")}
    env |= {"SMSPACE_TEST_MARK": marker, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    lake = tmp_path / "lake"
    ray_args = ["--executor", "ray", "--workers", "2", "--lake", str(lake)]
    proc = subprocess.Popen(
        [str(BIN / "smgen"), "generate", *GRID, "--mode", "MME", *ray_args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={k: str(v) for k, v in env.items()},
    )
    seen, names = 0, set()
    while proc.poll() is None:
        marked = set(processes_marked(marker))
        names |= {psutil.Process(p).name() for p in marked if psutil.pid_exists(p)}
        seen = max(seen, assert_loopback_only(marked))
        time.sleep(0.1)
    _, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 0, stderr
    assert seen >= 4 and {"gcs_server", "raylet"} <= names, (seen, names)  # Ray's servers were watched
    assert dataset_files(local_files(lake), "grid-seed3-MME") == dataset_files(local_files(grid_lake), "grid-seed3-MME")
    assert processes_marked(marker) == []


@pytest.mark.slow
def test_a_sweep_on_the_two_node_cluster_trains_every_run(ray_cluster, tmp_path):
    cluster, _ = ray_cluster
    args = ["sweep", "--setup", "grid", "--worlds", 1, "--seed", 3, "--transitions", 6000, "--steps", 20]
    args += ["--eval-every", 10, "--lake", tmp_path / "lake", "--out", tmp_path / "runs", "--executor", "ray"]
    proc = subprocess.run(
        [str(BIN / "smtrain"), *map(str, args), "--max-ensemble", "1"],
        capture_output=True,
        text=True,
        env={**os.environ, "RAY_ADDRESS": cluster.address},
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    finished = [json.loads(p.read_text())["state"] for p in sorted((tmp_path / "runs").glob("*/status.json"))]
    assert finished == ["finished"] * 3
    assert assert_loopback_only(tree(os.getpid())) >= 2


def _ray_generation(tmp_path) -> tuple[subprocess.Popen, set[int]]:
    """A long `smgen generate --executor ray` and every process of its tree once Ray's agents run."""
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER")}
    env |= {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    args = ["generate", "--setup", "grid", "--mode", "all", "--worlds", "30", "--transitions", "200000"]
    proc = subprocess.Popen(
        [str(BIN / "smgen"), *args, "--executor", "ray", "--workers", "2", "--lake", str(tmp_path / "lake")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    seen: set[int] = set()
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        seen |= tree(proc.pid)
        names = {psutil.Process(p).name() for p in seen if psutil.pid_exists(p)}
        if {"ray::DashboardAgent", "ray::RuntimeEnvAgent"} <= names and list((tmp_path / "lake").glob("*/shard-*")):
            return proc, seen
        time.sleep(0.2)
    proc.kill()
    raise AssertionError(f"Ray's agents never showed up: {proc.communicate()}")


def _gone_within(pids: set[int], seconds: float) -> list[str]:
    deadline = time.time() + seconds
    while time.time() < deadline:
        running = alive(pids)
        if not running:
            return []
        time.sleep(0.2)
    return [psutil.Process(p).name() for p in running if psutil.pid_exists(p)]


@pytest.mark.slow
def test_sigterm_stops_a_ray_command_as_ctrl_c_does(tmp_path):
    """Ray's own SIGTERM handler printed a stack dump and exited 1; now "interrupted" and 130, and
    every process of the command, Ray's agents included, is gone within seconds."""
    pytest.importorskip("ray")
    proc, pids = _ray_generation(tmp_path)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].startswith("interrupted; the parts already stored are kept"), stderr
    assert _gone_within(pids, 10) == []


@pytest.mark.slow
def test_a_killed_ray_driver_leaves_no_ray_process_behind(tmp_path):
    """kill -9 of the command: Ray's agents used to live on for 60-70 s."""
    pytest.importorskip("ray")
    proc, pids = _ray_generation(tmp_path)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert _gone_within(pids, 10) == []
