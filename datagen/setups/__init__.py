"""The registry of setups: it only collects what each setup's module declares (docs/MODEL.md §2)."""

from __future__ import annotations

from smspace.common.errors import SmspaceError
from smspace.datagen.setups import arm, grid
from smspace.datagen.setups.base import Setup, World, draw_transitions
from smspace.lake.transitions import MODES, Transitions

SETUPS: dict[str, Setup] = {s.name: s for s in (*grid.SETUPS, *arm.SETUPS)}


def get_setup(name: str) -> Setup:
    try:
        return SETUPS[name]
    except KeyError:
        raise SmspaceError(f"unknown setup {name!r} (choose from {', '.join(SETUPS)})") from None


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise SmspaceError(f"unknown mode {mode!r} (choose from {', '.join(MODES)} or all)")
    return mode


def parse_modes(text: str) -> list[str]:
    """--mode / --modes: one mode, several separated by commas, or all."""
    names = [m.strip() for m in text.split(",")]
    if names == ["all"]:
        return list(MODES)
    if "" in names:
        raise SmspaceError(f"--modes {text!r} has an empty entry (give e.g. MEM,MM or all)")
    modes = [check_mode(m) for m in names]
    if len(set(modes)) != len(modes):
        raise SmspaceError(f"--modes {text!r} names a mode twice")
    return modes


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
]
