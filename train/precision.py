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
from pathlib import Path

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


# auto compiles a session whose run-steps (steps left x runs trained together) repay compilation.
# benchmarks/bench_ensemble.py, 30 grid runs stacked, one core: the first compiled step took 19 s
# with an empty inductor cache and 2.8 s with a warm one, and a compiled step saved 0.23 ms per
# run-step (1.21 -> 0.97 ms; docs/SPEED.md). So compiling pays from ~85000 run-steps cold and
# ~12000 warm; auto asks for a margin over both.
AUTO_COMPILE_RUN_STEPS = 100_000  # with an empty inductor cache
AUTO_COMPILE_RUN_STEPS_WARM = 15_000  # where inductor's graph cache holds compiled graphs already


def compile_decision(asked: str, run_steps: int) -> str | None:
    """What --compile does in this session, as recorded in config.json's session: "torch.compile"
    (with why, under auto), or "eager: why"; None when not asked (off). One probe per process, the
    same decision the steps act on (`compiles`). `run_steps`: what this session will train."""
    if asked == "off":
        return None
    auto = asked == "auto"
    if auto:
        if run_steps < AUTO_COMPILE_RUN_STEPS_WARM:
            return f"eager: auto, {run_steps} run-steps do not repay compilation"
        warm = _inductor_cache_warm()
        needed = AUTO_COMPILE_RUN_STEPS_WARM if warm else AUTO_COMPILE_RUN_STEPS
        cache = "a warm inductor cache" if warm else "an empty inductor cache"
        if run_steps < needed:
            return f"eager: auto, {run_steps} run-steps do not repay compilation with {cache} (from {needed})"
    problem = _compile_problem()
    if problem is not None:
        if not auto:
            _say_once(
                f"--compile: torch.compile does not work here ({problem}); training eagerly (recorded in config.json)"
            )
        return f"eager: torch.compile does not work here ({problem})"
    return f"torch.compile (auto: {run_steps} run-steps, {cache})" if auto else "torch.compile"


def _inductor_cache_warm() -> bool:
    """Whether inductor's graph cache here holds compiled graphs (a session compiled before): the
    next compilation of the same step then reads them instead of compiling again."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    graphs = Path(cache_dir()) / "fxgraph"
    return graphs.is_dir() and any(graphs.iterdir())


def compiles(decision: str | None) -> bool:
    return decision is not None and decision.startswith("torch.compile")


def compiled(fn: Callable, enabled: bool) -> Callable:
    """`fn` through torch.compile when the session's decision (`compile_decision`) says so."""
    return torch.compile(fn) if enabled else fn


def _say_once(line: str) -> None:
    """The fallback line, once per process (a sweep's workers hand it to the study's monitor)."""
    if not _checked.get("said"):
        _checked["said"] = "yes"
        say = _notes[0] if _notes else lambda text: print(text, file=sys.stderr, flush=True)
        say(line)


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
