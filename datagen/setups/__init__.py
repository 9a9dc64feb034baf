"""The registry of setups: it only collects what each setup's module declares (docs/MODEL.md §2),
and the setups other packages register under the entry-point group `smspace.setups` (an entry
point names a `Setup`, or a list of them; docs/API.md, "Plugins"). Plugins are loaded only when a
command needs one: their names come from the package metadata."""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points

from smspace.common.errors import SmspaceError
from smspace.datagen.setups import arm, grid
from smspace.datagen.setups.base import Setup, World, draw_transitions
from smspace.lake.transitions import MODES, Transitions, check_mode, parse_modes

ENTRY_POINTS = "smspace.setups"
SETUPS: dict[str, Setup] = {s.name: s for s in (*grid.SETUPS, *arm.SETUPS)}  # the built-in ones


@cache
def _plugins() -> dict[str, object]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINTS) if ep.name not in SETUPS}


def setup_names() -> tuple[str, ...]:
    """Every setup a command may name (the choices of --setup, for completion too)."""
    return (*SETUPS, *sorted(_plugins()))


@cache
def get_setup(name: str) -> Setup:
    if name in SETUPS:
        return SETUPS[name]
    ep = _plugins().get(name)
    if ep is None:
        raise SmspaceError(f"unknown setup {name!r} (choose from {', '.join(setup_names())})")
    try:
        found = ep.load()
    except Exception as e:
        raise SmspaceError(f"setup {name!r} ({ep.value}) cannot be loaded: {type(e).__name__}: {e}") from None
    for setup in found if isinstance(found, list | tuple) else [found]:
        if isinstance(setup, Setup) and setup.name == name:
            return setup
    raise SmspaceError(f"the entry point {ep.value} of setup {name!r} declares no Setup named {name!r}")


__all__ = [
    "MODES",
    "SETUPS",
    "Setup",
    "Transitions",
    "World",
    "check_mode",
    "draw_transitions",
    "get_setup",
    "parse_modes",
    "setup_names",
]
