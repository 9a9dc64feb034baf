"""The arm of smspace (docs/MODEL.md §2.3) in rooms whose views repeat: an ambiguity dial.

Level 0 is smspace's own arm room (walls, 16 distinct objects). Levels 1-3 are an open floor, with
no walls in view, whose texture is one motif (coloured discs on a coloured ground, drawn from the
world seed) tiled with a period of 24 m (level 1: never repeats where the camera can be), 1.5 m
(level 2) or 0.75 m (level 3). The camera's orientation is fixed in the world, so two camera
positions one period apart (along x or y) see the same image: the shorter the period, the more
positions of the arm's working disc (radius 1.5 m) share their view.

The levels change the motif's density with the period (3.6 discs per m² at 0.75 m, 1.5 elsewhere);
the period dial `floor1`, `floor2`, `floor3` and `floor24` (periods of 1, 2, 3 and 24 m) holds it at
2 discs per m², so that the period is all that differs.
"""

from __future__ import annotations

from smspace.datagen.setups.arm import ARM_DEFAULTS, ArmWorld
from smspace.datagen.setups.base import Setup
from smspace_ambiguous_room.floor import (
    DIAL_PERIODS,
    FIXED_DENSITY,
    PERIODS,
    PeriodicFloorWorld,
    discs_at_fixed_density,
)

__all__ = [
    "DIAL",
    "FLOOR1",
    "FLOOR2",
    "FLOOR3",
    "FLOOR24",
    "LEVEL0",
    "LEVEL1",
    "LEVEL2",
    "LEVEL3",
    "LEVELS",
    "PERIODS",
    "PeriodicFloorWorld",
]


def _level(name: str, period: float | None, description: str, discs: int | None = None) -> Setup:
    def build(seed: int):
        return ArmWorld(seed, 3) if period is None else PeriodicFloorWorld(seed, period, discs)

    return Setup(
        name,
        n_motor=3,
        description=description,
        build=build,
        encoder_layers=(150, 100, 50),
        default_transitions=60_000,
        **ARM_DEFAULTS,  # the arm's shifts, shards, Vulkan check, provenance and previews
    )


LEVEL0 = _level("ambig0", None, "ambiguity level 0: smspace's arm room (walls and 16 distinct objects)")
LEVEL1 = _level("ambig1", PERIODS[1], "ambiguity level 1: an open floor whose motif never repeats in view")
LEVEL2 = _level("ambig2", PERIODS[2], "ambiguity level 2: an open floor whose motif repeats every 1.5 m")
LEVEL3 = _level("ambig3", PERIODS[3], "ambiguity level 3: an open floor whose motif repeats every 0.75 m")
LEVELS = {0: LEVEL0, 1: LEVEL1, 2: LEVEL2, 3: LEVEL3}

# The period dial at a fixed motif density (2 discs per m²): floor1, floor2, floor3, floor24.
DIAL = {
    round(p): _level(
        f"floor{round(p)}",
        p,
        f"an open floor whose motif repeats every {p:g} m, at {FIXED_DENSITY:g} discs per m²",
        discs_at_fixed_density(p),
    )
    for p in DIAL_PERIODS
}
FLOOR1, FLOOR2, FLOOR3, FLOOR24 = DIAL[1], DIAL[2], DIAL[3], DIAL[24]
