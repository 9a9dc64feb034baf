"""The registry of setups: it only collects what each setup's module declares (docs/MODEL.md §2),
and the setups other packages register under the entry-point group `smspace.setups` (an entry
point names a `Setup`, or a list of them; docs/API.md, "Plugins"). Plugins are loaded only when a
command needs one: their names come from the package metadata."""

from __future__ import annotations

from smspace.common import plugins
from smspace.common.plugins import Plugin
from smspace.datagen.setups import arm, grid
from smspace.datagen.setups.base import Setup, World, draw_transitions
from smspace.lake.transitions import MODES, Transitions, check_mode, parse_modes

ENTRY_POINTS = "smspace.setups"
SETUPS: dict[str, Setup] = {s.name: s for s in (*grid.SETUPS, *arm.SETUPS)}  # the built-in ones


def _named(found: object, name: str) -> Setup | None:
    """The Setup called `name` among what an entry point declares (one Setup, or a list)."""
    for setup in found if isinstance(found, list | tuple) else [found]:
        if isinstance(setup, Setup) and setup.name == name:
            return setup
    return None


REGISTRY = plugins.Registry("setup", ENTRY_POINTS, tuple(SETUPS), SETUPS.__getitem__, _named)


def setup_names() -> tuple[str, ...]:
    """Every setup a command may name (the choices of --setup, for completion too)."""
    return REGISTRY.names()


def get_setup(name: str) -> Setup:
    return REGISTRY.get(name)


def setup_plugin(name: str) -> Plugin | None:
    """The package a setup comes from (None: smspace's own)."""
    return REGISTRY.plugin(name)


def setup_label(name: str) -> str:
    return REGISTRY.label(name)


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
