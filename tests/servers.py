"""Servers the tests start (a moto S3 server, Ray nodes): bound to 127.0.0.1, checked with `ss`,
stopped by process group, never by name."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import psutil

from tests.conftest import BIN

LOOPBACK = ("127.0.0.1", "[::1]", "[::ffff:127.0.0.1]")  # the last: IPv4 loopback on a dual-stack socket


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listeners() -> list[tuple[str, int]]:
    """(local address, pid) of every listening TCP socket, from `ss -ltnpH`."""
    out = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True, check=True).stdout
    found = []
    for line in out.splitlines():
        fields = line.split()
        address = fields[3].rsplit(":", 1)[0]
        found += [(address, int(pid)) for pid in re.findall(r"pid=(\d+)", line)]
    return found


def tree(root: int) -> set[int]:
    """A process and all its descendants that are alive."""
    try:
        proc = psutil.Process(root)
        return {root, *(c.pid for c in proc.children(recursive=True))}
    except psutil.NoSuchProcess:
        return set()


def assert_loopback_only(pids: set[int]) -> int:
    """Every socket these processes listen on is bound to 127.0.0.1; returns how many were seen."""
    mine = [(address, pid) for address, pid in listeners() if pid in pids]
    elsewhere = [(a, p) for a, p in mine if a not in LOOPBACK]
    assert not elsewhere, f"listening beyond 127.0.0.1: {elsewhere}"
    return len(mine)


def stop_group(proc: subprocess.Popen, timeout: float = 20) -> None:
    """Stop a process started with start_new_session=True and everything in its group."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout)


def children_of(pid: int) -> set[int]:
    """Processes whose parent is `pid`, listed so that one exiting mid-listing is skipped, not raised
    (a busy machine's processes come and go)."""
    return {p.pid for p in psutil.process_iter(["ppid"]) if p.info["ppid"] == pid}


def alive(pids: set[int] | list[int]) -> list[int]:
    """Those of `pids` still running (a zombie has ended); one that exits while checked is ended."""
    running = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                running.append(pid)
        except psutil.NoSuchProcess:
            continue
    return running


def processes_marked(marker: str) -> list[int]:
    """Processes whose environment carries SMSPACE_TEST_MARK=marker: all a command started, even
    daemons that left its process tree."""
    found = []
    for proc in psutil.process_iter():
        try:
            if proc.environ().get("SMSPACE_TEST_MARK") == marker:
                found.append(proc.pid)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return found


AUTH_FREE_ACTIONS = 3  # moto authenticates every request after these: create user, policy, key


@contextlib.contextmanager
def moto_s3(log: Path) -> Iterator[dict[str, str]]:
    """A moto S3 server on 127.0.0.1 that checks credentials; yields the environment a client needs
    (valid keys of an IAM user allowed everything, region, endpoint) with one bucket, `lake`."""
    import boto3

    port = free_port()
    env = {**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": str(AUTH_FREE_ACTIONS)}
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(BIN / "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        )
    try:
        endpoint = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
                break
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        base = {"AWS_EC2_METADATA_DISABLED": "true", "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": endpoint}
        iam = boto3.client(
            "iam",
            endpoint_url=endpoint,
            aws_access_key_id="bootstrap",
            aws_secret_access_key="x",
            region_name="us-east-1",
        )
        iam.create_user(UserName="smspace")
        policy = {"Version": "2012-10-17", "Statement": [{"Effect": "Allow", "Action": "*", "Resource": "*"}]}
        iam.put_user_policy(UserName="smspace", PolicyName="all", PolicyDocument=json.dumps(policy))
        key = iam.create_access_key(UserName="smspace")["AccessKey"]
        client_env = base | {"AWS_ACCESS_KEY_ID": key["AccessKeyId"], "AWS_SECRET_ACCESS_KEY": key["SecretAccessKey"]}
        boto3.client(
            "s3",
            endpoint_url=endpoint,
            aws_access_key_id=client_env["AWS_ACCESS_KEY_ID"],
            aws_secret_access_key=client_env["AWS_SECRET_ACCESS_KEY"],
            region_name="us-east-1",
        ).create_bucket(Bucket="lake")
        assert assert_loopback_only(tree(proc.pid)) >= 1  # the server itself, on 127.0.0.1 only
        yield client_env | {"SMSPACE_TEST_MOTO_PID": str(proc.pid)}
    finally:
        stop_group(proc)
        assert not tree(proc.pid)


def s3fs_for(env: dict[str, str]):
    import s3fs

    return s3fs.S3FileSystem(
        endpoint_url=env["AWS_ENDPOINT_URL"], key=env["AWS_ACCESS_KEY_ID"], secret=env["AWS_SECRET_ACCESS_KEY"]
    )


def remote_files(env, prefix: str) -> dict[str, bytes]:
    fs = s3fs_for(env)
    return {p[len(prefix) + 1 :]: fs.cat_file(p) for p in fs.find(prefix)}
