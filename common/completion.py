"""Shell completion values that click cannot know by itself: one of a list of choices (and
comma-separated lists of them, as modes are given), devices and the dataset ids of the lake named
on the command line. The choices come from the caller, so this module imports nothing of the
project. Click's own machinery does the rest
(README, "Shell completion": `eval "$(_SMGEN_COMPLETE=bash_source smgen)"`).

Everything here is quick and never fails: a completion that raises or hangs breaks the shell.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Callable, Sequence

from click.shell_completion import CompletionItem

from smspace.common.cli import default_lake

Completer = Callable[..., list[CompletionItem]]


def comma_list_completer(choices: Sequence[str]) -> Completer:
    """Completion of one choice, `all`, or the next choice of a comma-separated list (MEM,MM,…)."""

    def complete(ctx, param, incomplete: str) -> list[CompletionItem]:
        done, _, last = incomplete.rpartition(",")
        given = set(done.split(",")) if done else set()
        options = [c for c in choices if c not in given] + ([] if done else ["all"])
        prefix = f"{done}," if done else ""
        return [CompletionItem(prefix + c) for c in options if c.startswith(last)]

    return complete


def complete_devices(ctx, param, incomplete: str) -> list[CompletionItem]:
    """cpu, cuda, and cuda:N for each NVIDIA device node (torch is not imported: it takes seconds)."""
    gpus = sorted(glob.glob("/dev/nvidia[0-9]*"))
    names = ["cpu", "cuda", *(f"cuda:{i}" for i in range(len(gpus)))]
    return [CompletionItem(n) for n in names if n.startswith(incomplete)]


def complete_datasets(ctx, param, incomplete: str) -> list[CompletionItem]:
    """The dataset ids of the lake given by --lake (else $SMSPACE_LAKE or data/lake); nothing for a
    lake on object storage, which would mean a network call on every Tab."""
    lake = ctx.params.get("lake") or default_lake()
    if "://" in str(lake):
        return []
    try:
        names = sorted(e.name for e in os.scandir(lake) if e.is_dir() and os.path.exists(f"{e.path}/manifest.json"))
    except OSError:
        return []
    return [CompletionItem(n) for n in names if n.startswith(incomplete)]
