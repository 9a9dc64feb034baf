"""The ambiguity dial (examples/ambiguous-room, installed by scripts/setup.sh as a plugin) and the
measure of view ambiguity (metrics/ambiguity.py), on views the project renders."""

from __future__ import annotations

import numpy as np
import pytest

from smspace.datagen.setups import get_setup, setup_names
from smspace.lake.dataset import Dataset
from smspace.metrics.ambiguity import view_ambiguity
from smspace.study.file import load_study

from .conftest import ROOT, smgen


def test_the_levels_are_registered_and_the_study_file_grids_over_them():
    assert {"ambig0", "ambig1", "ambig2", "ambig3"} <= set(setup_names())
    study = load_study(ROOT / "examples" / "ambiguous-room" / "study.toml")
    assert [c["setup"] for c in study.combinations()] == ["ambig0", "ambig1", "ambig2", "ambig3"]
    assert study.worlds >= 4 and study.modes == ["MM", "MME"]


@pytest.mark.parametrize(("setup", "period"), [("ambig2", 1.5), ("ambig3", 0.75), ("floor1", 1.0), ("floor2", 2.0)])
def test_views_one_period_apart_are_the_same_and_half_a_period_apart_are_not(setup, period):
    world = get_setup(setup).build(1)
    xy = np.array([[0.4, -0.3], [-1.1, 0.9]])
    here = world.render(xy)
    assert here.std() > 5  # a floor with something to see

    def differing(shift: tuple[float, float]) -> float:
        """The share of pixel values that differ from `here` when the camera moves by `shift`."""
        return float((world.render(xy + np.array(shift)) != here).mean())

    # the same image, but for a pixel on a disc's edge that float rounding of the camera's pose flips
    assert differing((period, 0.0)) < 0.01 and differing((0.0, -period)) < 0.01
    assert differing((period / 2, 0.0)) > 0.2 and differing((0.0, period / 2)) > 0.2


def test_a_shorter_period_measures_as_more_ambiguous(tmp_path):
    """The measure of scripts/arm_ambiguity.py, on MM views of levels 1 (never repeats) and 3."""
    distances = {}
    for setup in ("ambig1", "ambig3"):
        result = smgen("generate", "--setup", setup, "--mode", "MM", "--transitions", 600, "--workers", 1,
                       "--lake", tmp_path)  # fmt: skip
        assert result.exit_code == 0, result.output
        tr = Dataset.open(f"{setup}-seed0-MM", tmp_path).read_all()
        distances[setup] = view_ambiguity(tr.p_t.astype(np.float64), tr.s_t)["lookalike_distance"]
    assert distances["ambig3"] > 3 * distances["ambig1"], distances


def test_the_period_dial_holds_the_motifs_density():
    """Levels 2 and 3 changed the motif's density with the period (1.33 and 3.6 discs per m²); the
    dial's floors draw 2 per m² at every period: the same discs, in the same proportions, per m²."""
    from smspace_ambiguous_room import DIAL
    from smspace_ambiguous_room.floor import TEXELS_PER_M

    assert {"floor1", "floor2", "floor3", "floor24"} <= set(setup_names())
    covered = {}
    for period, setup in DIAL.items():
        floor = get_setup(setup.name).build(0).floor
        assert floor.shape[0] == 24 * TEXELS_PER_M
        texels = np.ascontiguousarray(floor).view(np.uint32).ravel()  # one RGBA texel per value
        _, counts = np.unique(texels, return_counts=True)
        covered[period] = 1 - counts.max() / len(texels)  # the ground is the commonest colour
    # the share of the floor under discs, one world: alike across periods (a 3.6 vs 1.5 density doubled it)
    assert max(covered.values()) < 2 * min(covered.values()), covered
