"""The registry of setups: it only collects what each setup's module declares (docs/MODEL.md §2),
and the setups other packages register under the entry-point group `smspace.setups` (an entry
point names a `Setup`, or a list of them; docs/API.md, "Plugins"). Plugins are loaded only when a
command needs one: their names come from the package metadata."""

from __future__ import annotations

from functools import cache

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.common.plugins import Plugin
from smspace.datagen.setups import arm, grid
from smspace.datagen.setups.base import Setup, World, draw_transitions
from smspace.lake.transitions import MODES, Transitions, check_mode, parse_modes

ENTRY_POINTS = "smspace.setups"
SETUPS: dict[str, Setup] = {s.name: s for s in (*grid.SETUPS, *arm.SETUPS)}  # the built-in ones


def _plugins() -> dict[str, object]:
    return plugins.others(ENTRY_POINTS, "setup", tuple(SETUPS))


def setup_names() -> tuple[str, ...]:
    """Every setup a command may name (the choices of --setup, for completion too)."""
    return (*SETUPS, *sorted(_plugins()))


@cache
def _loaded(name: str) -> tuple[Setup, Plugin | None]:
    if name in SETUPS:
        return SETUPS[name], None
    ep = _plugins().get(name)
    if ep is None:
        raise SmspaceError(f"unknown setup {name!r} (choose from {', '.join(setup_names())})")
    found, plugin = plugins.load("setup", ep)
    for setup in found if isinstance(found, list | tuple) else [found]:
        if isinstance(setup, Setup) and setup.name == name:
            return setup, plugin
    raise SmspaceError(f"the entry point {ep.value} of setup {name!r} declares no Setup named {name!r}")


def get_setup(name: str) -> Setup:
    return _loaded(name)[0]


def setup_plugin(name: str) -> Plugin | None:
    """The package a setup comes from (None: smspace's own)."""
    return _loaded(name)[1]


def setup_label(name: str) -> str:
    return plugins.label("setup", name, setup_plugin(name))


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
    "setup_label",
    "setup_names",
    "setup_plugin",
]
