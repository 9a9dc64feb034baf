"""`smgen preview`: PNGs a person can look at before trusting a world or a dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from datagen.setups.arm import SHIFT_BOUND, ArmWorld, overhead_pixel, overhead_view

WORKSPACE_RADIUS = 1.5


def frame_grid(frames: np.ndarray, columns: int = 8, scale: int = 8, gap: int = 4) -> Image.Image:
    """Sensor frames (n, H, W, 3) uint8 tiled row by row, upscaled without smoothing."""
    n, h, w, _ = frames.shape
    rows = -(-n // columns)
    canvas = np.full((rows * (h * scale + gap) + gap, columns * (w * scale + gap) + gap, 3), 255, np.uint8)
    for i, frame in enumerate(frames):
        r, c = divmod(i, columns)
        y, x = gap + r * (h * scale + gap), gap + c * (w * scale + gap)
        canvas[y : y + h * scale, x : x + w * scale] = frame.repeat(scale, 0).repeat(scale, 1)
    return Image.fromarray(canvas)


def room_map(world: ArmWorld, size: int = 512) -> Image.Image:
    """The room from above with the arm's working space and where shifts can put the camera."""
    world.positions(np.array([[0.25, -0.5, 0.25] + [0.0] * (world.n_motor - 3)]))  # pose the arm visibly
    image = Image.fromarray(overhead_view(world, size))
    draw = ImageDraw.Draw(image)

    def px(x: float, y: float) -> tuple[float, float]:
        return overhead_pixel(x, y, size)

    r = px(WORKSPACE_RADIUS, 0)[1] - px(0, 0)[1]
    c0 = px(0, 0)
    draw.ellipse([c0[0] + r, c0[1] + r, c0[0] - r, c0[1] - r], outline=(255, 255, 255), width=2)
    a, b = px(SHIFT_BOUND, SHIFT_BOUND), px(-SHIFT_BOUND, -SHIFT_BOUND)
    draw.rectangle([a[0], a[1], b[0], b[1]], outline=(255, 220, 0), width=2)
    reach = SHIFT_BOUND + WORKSPACE_RADIUS
    a, b = px(reach, reach), px(-reach, -reach)
    draw.rounded_rectangle([a[0], a[1], b[0], b[1]], radius=abs(r), outline=(255, 120, 0), width=2)
    draw.text((6, 6), "white: arm working space (|p| <= 1.5)", fill=(255, 255, 255))
    draw.text((6, 18), "yellow: shift range (+-1.75)   orange: camera reach", fill=(255, 220, 0))
    draw.text((6, size - 16), "+x up, +y left", fill=(255, 255, 255))
    return image


def sensory_table_image(table: np.ndarray, scale: int = 24) -> Image.Image:
    """The grid world's S[r, c, i] as one grey panel per component (black = min, white = max)."""
    panels = []
    for i in range(table.shape[2]):
        t = table[:, :, i]
        g = np.round(255 * (t - t.min()) / max(t.max() - t.min(), 1e-12)).astype(np.uint8)
        panel = np.pad(g.repeat(scale, 0).repeat(scale, 1), 4, constant_values=255)
        panels.append(np.repeat(panel[..., None], 3, axis=2))
    return Image.fromarray(np.concatenate(panels, axis=1))


def write_previews(out: Path, world, frames: np.ndarray | None) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if isinstance(world, ArmWorld):
        path = out / "room.png"
        room_map(world).save(path)
        written.append(path)
    else:
        path = out / "sensory_table.png"
        sensory_table_image(world.table).save(path)
        written.append(path)
    if frames is not None and frames.ndim == 4:
        path = out / "frames.png"
        frame_grid(frames).save(path)
        written.append(path)
    return written
