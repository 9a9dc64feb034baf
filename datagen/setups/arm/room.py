"""The random room of docs/MODEL.md §2.3 as plain data, drawn from a seed: no SAPIEN needed to describe it.

Textures are procedural (we ship no image assets we did not make).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

ROOM_HALF = 3.5
WALL_HEIGHT = 2.3
CELL_CENTRES = (-2.625, -0.875, 0.875, 2.625)
JITTER = 0.3
SHAPES = ("box", "sphere", "cylinder", "capsule")
N_HUES = 12


@dataclass(frozen=True)
class RoomObject:
    shape: str
    x: float
    y: float
    yaw: float
    rgb: tuple[float, float, float]


@dataclass(frozen=True)
class Room:
    floor_texture: np.ndarray  # (H, W, 4) uint8 RGBA
    wall_texture: np.ndarray
    objects: tuple[RoomObject, ...]


def hue_rgb(k: int) -> tuple[float, float, float]:
    """One of the 12 object colours: hue k/12, HSV saturation = value = 0.9."""
    r, g, b = colorsys.hsv_to_rgb(k / N_HUES, 0.9, 0.9)
    return (r, g, b)


def procedural_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Two colours mixed by a random pattern (checks, stripes, smooth noise or bricks)."""
    hue = rng.uniform()
    sat, val = rng.uniform(0.25, 0.7), rng.uniform(0.45, 0.9)
    c1 = np.array(colorsys.hsv_to_rgb(hue, sat, val))
    c2 = np.array(colorsys.hsv_to_rgb((hue + rng.uniform(0.08, 0.5)) % 1.0, sat, val * rng.uniform(0.45, 0.8)))
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    kind = int(rng.integers(0, 4))
    if kind == 0:
        kx, ky = rng.integers(3, 9, 2)
        mix = ((np.floor(x * kx) + np.floor(y * ky)) % 2).astype(float)
    elif kind == 1:
        k, angle = rng.integers(3, 10), rng.uniform(0, np.pi)
        mix = 0.5 + 0.5 * np.sin(2 * np.pi * k * (x * np.cos(angle) + y * np.sin(angle)))
    elif kind == 2:
        coarse = rng.uniform(0, 1, (5, 5))
        iy, ix = y * 4, x * 4
        y0, x0 = np.floor(iy).astype(int), np.floor(ix).astype(int)
        fy, fx = iy - y0, ix - x0
        y1, x1 = np.minimum(y0 + 1, 4), np.minimum(x0 + 1, 4)
        mix = (
            coarse[y0, x0] * (1 - fx) * (1 - fy)
            + coarse[y0, x1] * fx * (1 - fy)
            + coarse[y1, x0] * (1 - fx) * fy
            + coarse[y1, x1] * fx * fy
        )
    else:
        rows = rng.integers(4, 9)
        row = np.floor(y * rows)
        shifted = x * rows / 2 + 0.5 * (row % 2)
        mortar = (np.abs(y * rows - np.round(y * rows)) < 0.08) | (np.abs(shifted - np.round(shifted)) < 0.06)
        mix = mortar.astype(float)
    rgb = c1 * (1 - mix[..., None]) + c2 * mix[..., None] + rng.normal(0, 0.02, (height, width, 3))
    rgba = np.concatenate([np.clip(rgb, 0, 1), np.ones((height, width, 1))], axis=2)
    return np.round(rgba * 255).astype(np.uint8)


def draw_room(rng: np.random.Generator) -> Room:
    floor = procedural_texture(rng, 64, 64)
    wall = procedural_texture(rng, 24, 72)  # a wall is 7 wide and 2.3 high
    objects = []
    for cy in CELL_CENTRES:
        for cx in CELL_CENTRES:
            jx, jy = rng.uniform(-JITTER, JITTER, 2)
            objects.append(
                RoomObject(
                    shape=SHAPES[int(rng.integers(0, len(SHAPES)))],
                    x=float(cx + jx),
                    y=float(cy + jy),
                    yaw=float(rng.uniform(-np.pi, np.pi)),
                    rgb=hue_rgb(int(rng.integers(0, N_HUES))),
                )
            )
    return Room(floor, wall, tuple(objects))
