"""What a person looks at for an arm world: the room from above with the arm's reach (for
`smgen preview`) and the camera's positions on that map (for `smgen view`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smspace.datagen.setups.arm.world import SHIFT_BOUND, ArmWorld, overhead_pixel, overhead_view
from smspace.lake.transitions import Transitions

WORKSPACE_RADIUS = 1.5
BLUE, ORANGE = (40, 110, 230), (240, 140, 20)


def room_map(world: ArmWorld, size: int = 512):
    """The room from above with the arm's working space and where shifts can put the camera."""
    from PIL import Image, ImageDraw

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


def write_preview(world: ArmWorld, out: Path) -> list[Path]:
    path = out / "room.png"
    room_map(world).save(path)
    return [path]


def log_room_map(rec, world: ArmWorld, tr: Transitions, times: list) -> None:
    """The room map with the camera at t (blue) and t+1 (orange) on the recording's timeline."""
    import rerun as rr

    rec.log("map/room", rr.Image(np.asarray(room_map(world))), static=True)
    n = len(tr)
    for name, p, shift, colour in (("camera_t", tr.p_t, tr.shift_t, BLUE), ("camera_t1", tr.p_t1, tr.shift_t1, ORANGE)):
        xy = (p + shift).astype(np.float64)
        px = np.stack(overhead_pixel(xy[:, 0], xy[:, 1]), axis=1)
        rec.send_columns(
            f"map/{name}",
            indexes=times,
            columns=rr.Points2D.columns(positions=px, colors=[colour] * n, radii=[5.0] * n),
        )
