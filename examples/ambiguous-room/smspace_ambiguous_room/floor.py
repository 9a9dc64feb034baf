"""An open floor whose texture repeats with a period: the arm and camera of smspace's ArmWorld,
the room replaced.

The floor is 24 m square, centred on the arm's base, with 64 texels per metre; a period divides
24 m into whole tiles of whole texels, so the texture is exactly periodic in room coordinates and
two camera positions one period apart render the same image. No wall is in view: the camera's
highest ray meets the floor 6.8 m ahead, and the camera never leaves ±3.25 m (|p| ≤ 1.5 plus a
shift of at most 1.75), so it sees floor up to 10.1 m, inside the floor's 12.
"""

from __future__ import annotations

import colorsys

import numpy as np

from smspace.datagen.setups.arm import ArmWorld

FLOOR_HALF = 12.0
TEXELS_PER_M = 64
PERIODS = {1: 24.0, 2: 1.5, 3: 0.75}  # by level; level 0 is smspace's room
# Levels 1-3 draw max(2, round(1.5 p²)) discs per tile: 1.5 per m², but 3.6 per m² at 0.75 m, so
# that their period and their motif's density changed together. The period dial (floor1 … floor24)
# holds the density at FIXED_DENSITY: exactly 2 p² discs per tile, whatever the period.
DISCS_PER_M2 = 1.5
FIXED_DENSITY = 2.0
DIAL_PERIODS = (1.0, 2.0, 3.0, 24.0)  # each divides the floor and holds a whole number of discs


def discs_at_fixed_density(period: float) -> int:
    count = FIXED_DENSITY * period**2
    if abs(count - round(count)) > 1e-9 or round(count) < 1:
        raise ValueError(f"a period of {period} m holds {count} discs at {FIXED_DENSITY} per m², not a whole number")
    return round(count)


def motif(rng: np.random.Generator, period: float, discs: int | None = None) -> np.ndarray:
    """One tile (period × period m) of coloured discs on a coloured ground, drawn on a torus so
    that tiles join without a seam; RGBA uint8. `discs`: how many (None: the levels' count)."""
    size = round(period * TEXELS_PER_M)
    ground = np.array(colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.2, 0.5), rng.uniform(0.5, 0.8)))
    image = np.broadcast_to(ground, (size, size, 3)).copy()
    yy, xx = np.mgrid[0:size, 0:size] / TEXELS_PER_M  # metres within the tile
    for _ in range(max(2, round(DISCS_PER_M2 * period**2)) if discs is None else discs):
        cx, cy = rng.uniform(0, period, 2)
        radius = rng.uniform(0.08, 0.25)
        dx = np.abs(xx - cx)
        dy = np.abs(yy - cy)
        dx, dy = np.minimum(dx, period - dx), np.minimum(dy, period - dy)  # on the torus
        inside = dx**2 + dy**2 <= radius**2
        image[inside] = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.6, 0.95), rng.uniform(0.6, 0.95))
    rgba = np.concatenate([image, np.ones((size, size, 1))], axis=2)
    return np.round(rgba * 255).astype(np.uint8)


def floor_texture(seed: int, period: float, discs: int | None = None) -> np.ndarray:
    tiles = round(2 * FLOOR_HALF / period)
    if abs(tiles * period - 2 * FLOOR_HALF) > 1e-9 or abs(period * TEXELS_PER_M - round(period * TEXELS_PER_M)) > 1e-9:
        raise ValueError(f"a period of {period} m does not tile the {2 * FLOOR_HALF} m floor in whole texels")
    tile = motif(np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,))), period, discs)
    return np.tile(tile, (tiles, tiles, 1))


class PeriodicFloorWorld(ArmWorld):
    """smspace's 3-joint arm and camera above a periodic floor (no walls, no objects)."""

    def __init__(self, world_seed: int, period: float, discs: int | None = None):
        super().__init__(world_seed, 3)
        self.period = period
        self.floor = floor_texture(world_seed, period, discs)

    def _build_room(self, sapien, scene):
        """The floor only, a square of two triangles whose texture coordinates span the whole
        texture once (a box's would fold it into a cube's unwrapping); returns (entity, position,
        quaternion) as ArmWorld's rooms do."""
        h = FLOOR_HALF
        mesh = sapien.render.RenderShapeTriangleMesh(
            np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float32),
            np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
            np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
            np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
            self._textured(sapien, self.floor),
        )
        body = sapien.render.RenderBodyComponent()
        body.attach(mesh)
        entity = sapien.Entity()
        entity.add_component(body)
        pose, q = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        entity.set_pose(sapien.Pose(pose, q))
        scene.add_entity(entity)
        return [(entity, pose, q)]
