"""Worker processes are spawned: each imports the caller's script again, so a script that starts
workers at its top level starts them again in every worker — two tracebacks and a half-made
study folder. Found before anything is written, and said in one line with what to write."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from smspace.common.errors import SmspaceError


def _guards(tree: ast.Module) -> list[tuple[int, int]]:
    """The line ranges of `if __name__ == "__main__":` blocks."""
    spans = []
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare):
            names = {getattr(n, "id", None) for n in [node.test.left, *node.test.comparators]}
            values = {getattr(n, "value", None) for n in [node.test.left, *node.test.comparators]}
            if "__name__" in names and "__main__" in values:
                spans.append((node.lineno, node.end_lineno or node.lineno))
    return spans


def unguarded_call() -> tuple[str, int] | None:
    """(script, line) where the running script's top level reaches this call outside a
    `__main__` guard; None for a guarded call, a console script, `python -c`, a notebook."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if main is None or not path or not str(path).endswith(".py"):
        return None
    frame, line = sys._getframe(1), None
    while frame is not None:  # the outermost frame of the script's own top level
        if frame.f_globals is main.__dict__ and frame.f_code.co_name == "<module>":
            line = frame.f_lineno
        frame = frame.f_back
    if line is None:
        return None
    try:
        tree = ast.parse(Path(path).read_text(), path)
    except (OSError, SyntaxError, ValueError):
        return None  # cannot tell: let it run as before
    if any(first <= line <= last for first, last in _guards(tree)):
        return None
    return str(path), line


def refuse_unguarded(call: str) -> None:
    """Refuse `call` (what the caller wrote, e.g. `smspace.run_study(workers=2)`) from a script's
    unguarded top level."""
    where = unguarded_call()
    if where is not None:
        script, line = where
        raise SmspaceError(
            f"{script}:{line}: {call} starts worker processes, which import this script again and would "
            'run it again; put the call under `if __name__ == "__main__":` (docs/API.md, "Scripts that start workers")'
        )
