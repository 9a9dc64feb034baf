"""The arm in a room (docs/MODEL.md §2.3, §2.4): `arm` (3 revolute joints) and `arm6` (4 revolute,
2 prismatic). SAPIEN is imported only when a world is first rendered."""

from __future__ import annotations

from smspace.datagen.setups.arm.views import log_room_map, write_preview
from smspace.datagen.setups.arm.vulkan import render_provenance, require_render_device
from smspace.datagen.setups.arm.world import SHIFT_BOUND, ArmWorld, planar_fk
from smspace.datagen.setups.base import Setup


def _builder(n_motor: int):
    def build(seed: int) -> ArmWorld:
        return ArmWorld(seed, n_motor)

    return build


# What every arm setup shares (a plugin's arm in another room reuses it: examples/ambiguous-room)
ARM_DEFAULTS = dict(
    shift_bound=SHIFT_BOUND,
    default_shard_size=8192,
    default_walk_step=0.1,  # a standard deviation per motor per step, of the motor range [-1, 1]
    bytes_per_transition=640,
    preflight=require_render_device,
    provenance=render_provenance,
    preview=write_preview,
    view_world=log_room_map,
)

SETUPS = (
    Setup(
        "arm",
        n_motor=3,
        description="3-joint arm with a 16×16 camera in a room (docs/MODEL.md §2.3)",
        build=_builder(3),
        encoder_layers=(150, 100, 50),
        default_transitions=150_000,
        **ARM_DEFAULTS,
    ),
    Setup(
        "arm6",
        n_motor=6,
        description="6-joint arm (2 prismatic) in a room (docs/MODEL.md §2.4)",
        build=_builder(6),
        encoder_layers=(500, 400, 300, 200),
        default_transitions=300_000,
        **ARM_DEFAULTS,
    ),
)

__all__ = ["ARM_DEFAULTS", "SETUPS", "ArmWorld", "planar_fk"]
