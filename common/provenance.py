"""What a computation ran on, recorded beside its numbers: smspace's version and git commit (in a
checkout), torch, Python, the CPU and the vector extensions its kernels chose from, the device.
A run's config.json lists one such record per training session (created, resumed, extended)."""

from __future__ import annotations

import datetime
import platform
import socket
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
# the extensions that decide which kernels torch and MKL/oneDNN pick (hence the summation order)
VECTOR_FLAGS = ("sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512bw", "avx512vl", "avx512_vnni",
                "avx512_bf16", "avx512_fp16", "amx_tile", "amx_bf16", "amx_int8", "avx_vnni")  # fmt: skip


def version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "unknown"


@cache
def git_commit() -> str | None:
    """The commit of the checkout smspace runs from ("+dirty" with uncommitted changes), or None
    when installed from a wheel."""
    if not (REPO / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


@cache
def cpu() -> dict[str, Any]:
    """The CPU model and its vector extensions (Linux /proc/cpuinfo; the platform's name elsewhere)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and value.strip():
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                if model and flags:
                    break
    except OSError:
        pass
    return {"cpu": model, "cpu_vector_extensions": [f for f in VECTOR_FLAGS if f in flags]}


def device_name(device: str) -> str:
    """The accelerator a run trained on, by name ("cpu" for the CPU)."""
    if not device.startswith("cuda"):
        return device
    import torch

    try:
        return f"{device}: {torch.cuda.get_device_name(torch.device(device))}"
    except (RuntimeError, AssertionError):
        return device


def session(device: str, threads: int, **done: Any) -> dict[str, Any]:
    """One training session's record; `done`: what the session decided (how it compiled)."""
    import torch

    return done | {
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "smspace": version("smspace"),
        "git_commit": git_commit(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        **cpu(),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "device": device_name(device),
        "threads": threads,
        "host": socket.gethostname(),
    }
