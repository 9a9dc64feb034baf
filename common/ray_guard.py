"""Stops what a local Ray left running when the command that started it was killed (kill -9).

Ray fate-shares gcs_server and the raylet with its driver (they die with it), but the raylet's
agents (DashboardAgent, RuntimeEnvAgent) then spend 60 s reporting the raylet's death to the dead
GCS before they exit (a fixed timeout in Ray 2.60). This guardian, started beside a local Ray, keeps
a list of the Ray processes (pid and start time, so a reused pid is never touched) while the driver
lives; when its pipe from the driver closes without a "done" line, it kills the ones still running.

Run as `python -m common.ray_guard`; the driver writes the pids of Ray's own processes, one per line.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import sys
from pathlib import Path

POLL_S = 0.5
DONE = "done"


def _start_time(pid: int) -> int | None:
    """The kernel's start time of a process (field 22 of /proc/PID/stat), None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)", which may hold spaces
    return None if fields[0] == "Z" else int(fields[19])


def _children() -> dict[int, list[int]]:
    found: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            found.setdefault(ppid, []).append(int(entry))
    return found


def _descendants(roots: set[int]) -> set[int]:
    children, seen, todo = _children(), set(), list(roots)
    while todo:
        pid = todo.pop()
        if pid not in seen:
            seen.add(pid)
            todo += children.get(pid, [])
    return seen


def guard() -> None:
    roots: set[int] = set()
    known: dict[int, int] = {}  # pid -> start time of every Ray process seen so far
    buffered = ""
    while True:
        ready, _, _ = select.select([sys.stdin], [], [], POLL_S)
        if ready:
            chunk = os.read(sys.stdin.fileno(), 4096).decode()
            if not chunk:  # the driver is gone without saying it stopped Ray itself
                break
            buffered += chunk
            *lines, buffered = buffered.split("\n")
            for line in lines:
                if line.strip() == DONE:
                    return
                if line.strip().isdigit():
                    roots.add(int(line))
        for pid in _descendants(roots):
            started = _start_time(pid)
            if started is not None:
                known.setdefault(pid, started)
    for pid, started in known.items():
        if _start_time(pid) == started:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle
    guard()
