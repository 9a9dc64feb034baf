"""How the training step computes: its precision (fp32, or bf16 autocast of the network's matmuls)
and whether it goes through torch.compile. Evaluation (h, the metrics, the evaluation loss) is
always fp32 and eager; so are the weights, Adam's state and the loss.

`auto` is decided when a run is created and recorded as what it decided (config.json), so a run
resumed on another machine keeps its precision: bf16 only where the hardware multiplies bf16
natively (a CPU with AMX or AVX-512 BF16, a GPU that supports it), and only for what bf16 was
measured not to change (docs/REPRODUCTION.md, "bf16"): see AUTO_PICKS_BF16.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

import torch

from smspace.common import provenance

NATIVE_BF16_FLAGS = ("amx_bf16", "avx512_bf16")
# What the grid study in bf16 beside fp32 decided (docs/REPRODUCTION.md, "bf16"; 10 worlds x 100000
# steps): every claim holds, but bf16's rounding floor sets the near-zero values the paper reports,
# in 10 of 10 worlds each: MM's loss 184x fp32's, MM's D_topo 3x, MME's D_topo 1.6x and D_metric
# 2.5x. Reported numbers would change, so auto keeps fp32; bf16 is there to be asked for.
AUTO_PICKS_BF16 = False


def native_bf16(device: str) -> str | None:
    """Why this device multiplies bf16 natively ("this CPU has amx_bf16"), or None."""
    if device.startswith("cuda"):
        try:
            return "this GPU supports bf16" if torch.cuda.is_bf16_supported() else None
        except (RuntimeError, AssertionError):
            return None
    flags = [f for f in NATIVE_BF16_FLAGS if f in provenance.cpu()["cpu_vector_extensions"]]
    return f"this CPU has {' and '.join(flags)}" if flags else None


def resolve(precision: str, device: str) -> tuple[str, str]:
    """(fp32 or bf16, why): what `precision` means on `device`."""
    if precision != "auto":
        return precision, "asked for"
    native = native_bf16(device)
    if native is None:
        return "fp32", "auto: no native bf16 multiply here"
    if not AUTO_PICKS_BF16:
        return "fp32", f"auto: {native}, but bf16 raises the paper's near-zero values (docs/REPRODUCTION.md, bf16)"
    return "bf16", f"auto: {native}"


@contextlib.contextmanager
def autocast(precision: str, device: torch.device) -> Iterator[None]:
    """The forward pass of a training step in `precision` (matmuls only: autocast's bf16 list)."""
    if precision == "bf16":
        with torch.autocast(device.type, dtype=torch.bfloat16):
            yield
    else:
        yield


def compile_decision(enabled: bool) -> str | None:
    """What --compile does here, as recorded in each session of config.json: "torch.compile", or
    "eager: why" when torch.compile does not work here (inductor needs a C++ compiler on a CPU);
    None when not asked. One decision per process, the same one `compiled` acts on."""
    if not enabled:
        return None
    problem = _compile_problem()
    return "torch.compile" if problem is None else f"eager: torch.compile does not work here ({problem})"


def compiled(fn: Callable, enabled: bool, say: Callable[[str], None] | None = None) -> Callable:
    """`fn` through torch.compile when asked and when it works here: a tiny function is compiled
    first, and a failure is one line (said once per process), then eager."""
    decision = compile_decision(enabled)
    if decision is None:
        return fn
    if decision != "torch.compile":
        if not _checked.get("said"):
            _checked["said"] = "yes"
            say = say or (_notes[0] if _notes else lambda line: print(line, file=sys.stderr, flush=True))
            say(f"--compile: {decision.removeprefix('eager: ')}; training eagerly (recorded in config.json)")
        return fn
    return torch.compile(fn)


_checked: dict[str, str | None] = {}
_notes: list[Callable[[str], None]] = []


def say_notes_through(say: Callable[[str], None]) -> None:
    """Where this process says its --compile line: a sweep's workers hand it to the study's
    monitor, which says each line once for the whole sweep, not once per worker."""
    _notes[:] = [say]


def _compile_problem() -> str | None:
    if "result" not in _checked:
        try:
            probe = torch.compile(lambda x: torch.relu(x) * 2 + 1)
            probe(torch.ones(4))
            _checked["result"] = None
        except Exception as e:  # inductor raises many kinds (no compiler, a bad toolchain)
            _checked["result"] = _first_sentence(e)
    return _checked["result"]


def _first_sentence(e: BaseException) -> str:
    """The exception's type and its message's first line, whole: inductor's messages run on for
    pages, and a line cut at a fixed width ends mid-sentence."""
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__
