"""The registry of setups (SPEC 2): name → how to build a world and what it looks like."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from datagen.errors import SmspaceError
from datagen.setups.base import MODES, Transitions, World, draw_transitions


@dataclass(frozen=True)
class Setup:
    name: str
    n_motor: int
    default_transitions: int
    default_shard_size: int  # transitions per shard: arm shards are smaller so workers stay balanced
    shift_bound: float  # |shift component| ≤ shift_bound (the MM shift may sit outside: it is fixed)
    build: Callable[[int], World]
    description: str
    preflight: Callable[[], None] = lambda: None  # fails early (before anything is written) if unusable


def _render_device() -> None:
    from datagen.setups.vulkan import require_render_device

    require_render_device()


def _grid(n_motor: int) -> Callable[[int], World]:
    def build(seed: int) -> World:
        from datagen.setups.grid import GridWorld

        return GridWorld(seed, n_motor)

    return build


def _arm(n_motor: int) -> Callable[[int], World]:
    def build(seed: int) -> World:
        from datagen.setups.arm import ArmWorld  # imports SAPIEN lazily: grid users never pay for it

        return ArmWorld(seed, n_motor)

    return build


SETUPS: dict[str, Setup] = {
    s.name: s
    for s in (
        Setup(
            "grid",
            n_motor=3,
            default_transitions=150_000,
            default_shard_size=32768,
            shift_bound=10.0,
            build=_grid(3),
            description="10×10 torus, 3 motors, 4 sensors (SPEC 2.1)",
        ),
        Setup(
            "grid6",
            n_motor=6,
            default_transitions=150_000,
            default_shard_size=32768,
            shift_bound=10.0,
            build=_grid(6),
            description="10×10 torus, 6 mixed motors (SPEC 2.2)",
        ),
        Setup(
            "arm",
            n_motor=3,
            default_transitions=150_000,
            default_shard_size=8192,
            shift_bound=1.75,
            build=_arm(3),
            description="3-joint arm with a 16×16 camera in a room (SPEC 2.3)",
            preflight=_render_device,
        ),
        Setup(
            "arm6",
            n_motor=6,
            default_transitions=300_000,
            default_shard_size=8192,
            shift_bound=1.75,
            build=_arm(6),
            description="6-joint arm (2 prismatic) in a room (SPEC 2.4)",
            preflight=_render_device,
        ),
    )
}


def get_setup(name: str) -> Setup:
    try:
        return SETUPS[name]
    except KeyError:
        raise SmspaceError(f"unknown setup {name!r} (choose from {', '.join(SETUPS)})") from None


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise SmspaceError(f"unknown mode {mode!r} (choose from {', '.join(MODES)} or all)")
    return mode


__all__ = ["MODES", "SETUPS", "Setup", "Transitions", "World", "check_mode", "draw_transitions", "get_setup"]
