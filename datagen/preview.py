"""`smgen preview`: PNGs a person can look at before trusting a world or a dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smspace.datagen.parts import world_for
from smspace.datagen.setups import get_setup
from smspace.lake.dataset import Dataset

FRAMES_SEED_KEY = 2  # spawn key of the random positions shown when previewing a world without a dataset


def frame_grid(frames: np.ndarray, columns: int = 8, scale: int = 8, gap: int = 4):
    """Sensor frames (n, H, W, 3) uint8 tiled row by row, upscaled without smoothing."""
    from PIL import Image

    n, h, w, _ = frames.shape
    rows = -(-n // columns)
    canvas = np.full((rows * (h * scale + gap) + gap, columns * (w * scale + gap) + gap, 3), 255, np.uint8)
    for i, frame in enumerate(frames):
        r, c = divmod(i, columns)
        y, x = gap + r * (h * scale + gap), gap + c * (w * scale + gap)
        canvas[y : y + h * scale, x : x + w * scale] = frame.repeat(scale, 0).repeat(scale, 1)
    return Image.fromarray(canvas)


def _write(out: Path, setup_name: str, seed: int, frames: np.ndarray | None) -> list[Path]:
    setup = get_setup(setup_name)
    world = world_for(setup.name, seed)
    out.mkdir(parents=True, exist_ok=True)
    written = setup.preview(world, out) if setup.preview else []
    if frames is not None and frames.ndim == 4:  # images; a grid's few components say nothing as pictures
        path = out / "frames.png"
        frame_grid(frames).save(path)
        written.append(path)
    return written


def preview_dataset(ds: Dataset, out: Path, n_frames: int) -> list[Path]:
    """The dataset's world and its first sensor frames, as stored."""
    return _write(out, ds.manifest.setup, ds.manifest.world_seed, ds.read_all(n_frames).s_t)


def preview_world(setup_name: str, seed: int, out: Path, n_frames: int) -> list[Path]:
    """A world without a dataset: frames seen from random positions of the arm, the room unshifted."""
    setup = get_setup(setup_name)
    setup.preflight()
    world = world_for(setup.name, seed)
    frames = None
    if world.sensor_dtype == np.uint8:
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FRAMES_SEED_KEY,)))
        _, p = world.sample_motors(rng, n_frames)
        frames = world.sense(p, np.zeros_like(p))
    return _write(out, setup.name, seed, frames)
