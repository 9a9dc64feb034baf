"""Walks (datagen/walks.py) and their invariants (lake/episodes.py), on the grid, the six-motor
grid and the arm: each step starts where the one before ended, the environment keeps still where
the mode says, the walk stays in bounds and takes steps no larger than asked, the same seed draws
the same walk, and a broken copy is named at the row it breaks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from smspace.common.errors import SmspaceError
from smspace.datagen.setups.arm import ArmWorld
from smspace.datagen.setups.grid import LEVELS, GridWorld
from smspace.datagen.walks import continuous_walk, draw_walks, lattice_walk, reflect
from smspace.lake.episodes import episode_problem
from smspace.lake.transitions import MODES


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


@pytest.mark.parametrize("n_motor", [3, 6])
@pytest.mark.parametrize("mode", MODES)
def test_grid_walks_keep_every_invariant(n_motor, mode):
    world = GridWorld(1, n_motor)
    walks = draw_walks(world, mode, rng(), episodes=7, length=40, step=1)
    t = walks.transitions
    assert len(t) == 280
    assert episode_problem(t, walks.episode, walks.step, mode) is None
    # every state is one of the world's, with its own position and sensation
    index = {tuple(m): i for i, m in enumerate(world.motors.astype(np.float32))}
    rows = np.array([index[tuple(m)] for m in t.m_t])
    np.testing.assert_array_equal(t.p_t, world.positions[rows].astype(np.float32))
    np.testing.assert_array_equal(t.s_t, world.sense(world.positions[rows], t.shift_t.astype(np.float64)))
    shifts_per_episode = [len(np.unique(t.shift_t[walks.episode == e], axis=0)) for e in range(7)]
    if mode == "MM":
        assert len(np.unique(t.shift_t, axis=0)) == 1
    elif mode == "MME":
        assert shifts_per_episode == [1] * 7 and len(np.unique(t.shift_t, axis=0)) > 1
    else:
        assert min(shifts_per_episode) > 1 and np.any(t.shift_t != t.shift_t1)


def test_lattice_steps_are_bounded_and_the_walk_covers_the_lattice():
    idx = lattice_walk(rng(3), 3, len(LEVELS), episodes=4, length=3000, step=1)
    levels = np.stack(np.unravel_index(idx, (5, 5, 5)), axis=-1)
    assert np.abs(np.diff(levels, axis=1)).max() == 1
    assert len(np.unique(idx)) == 125
    wide = lattice_walk(rng(3), 3, 5, episodes=4, length=3000, step=2)
    assert np.abs(np.diff(np.stack(np.unravel_index(wide, (5, 5, 5)), -1), axis=1)).max() == 2


def test_continuous_walk_is_bounded_seeded_and_steps_as_asked():
    m = continuous_walk(rng(5), 3, episodes=50, length=200, step=0.05)
    assert m.min() >= -1.0 and m.max() <= 1.0
    moves = np.diff(m, axis=1)
    assert 0.04 < moves.std() < 0.06  # reflection only shortens a move
    np.testing.assert_array_equal(m, continuous_walk(rng(5), 3, 50, 200, 0.05))
    assert not np.array_equal(m, continuous_walk(rng(6), 3, 50, 200, 0.05))


def test_reflect_folds_like_a_mirror():
    folded = reflect(np.array([1.5, -1.25, 3.5, 0.3, -5.0]), -1.0, 1.0)
    np.testing.assert_allclose(folded, [0.5, -0.75, -0.5, 0.3, -1.0])


def test_same_seed_same_walk_bytes():
    a = draw_walks(GridWorld(0), "MEM", rng(9), 3, 20, 1).transitions
    b = draw_walks(GridWorld(0), "MEM", rng(9), 3, 20, 1).transitions
    for name, col in a.columns().items():
        assert col.tobytes() == getattr(b, name).tobytes(), name


def test_arm_walks_keep_every_invariant():
    world = ArmWorld(0)
    walks = draw_walks(world, "MME", rng(), episodes=2, length=12, step=0.1)
    t = walks.transitions
    assert t.s_t.shape == (24, 16, 16, 3) and t.s_t.dtype == np.uint8
    assert episode_problem(t, walks.episode, walks.step, "MME") is None
    np.testing.assert_allclose(t.p_t, world.positions(t.m_t.astype(np.float64)), atol=1e-6)


@pytest.mark.parametrize(
    "breakage, named",
    [
        ("gap", "goes from step 3 to 5"),
        ("teleport", "m_t is not the m_t1 of the step before"),
        ("late start", "starts at step 1"),
        ("moved world", "the environment moves between episodes in MM"),
        ("order", "episodes out of order"),
    ],
)
def test_a_broken_walk_is_named(breakage, named):
    walks = draw_walks(GridWorld(0), "MM", rng(), episodes=3, length=10, step=1)
    t, episode, step = walks.transitions, walks.episode.copy(), walks.step.copy()
    if breakage == "gap":
        step[4:10] += 1
    elif breakage == "teleport":
        m = t.m_t.copy()
        m[5] = -m[5] + 0.5
        t = replace(t, m_t=m)
    elif breakage == "late start":
        step[10:20] += 1
    elif breakage == "moved world":
        shift = t.shift_t.copy()
        shift[10:20] += 1
        t = replace(t, shift_t=shift, shift_t1=shift.copy())
    else:
        episode[:10] = 2
    problem = episode_problem(t, episode, step, "MM")
    assert problem is not None and named in problem, problem


def test_a_world_that_cannot_walk_is_named():
    class Teleporter:
        pass

    with pytest.raises(SmspaceError, match="Teleporter cannot walk"):
        draw_walks(Teleporter(), "MM", rng(), 1, 1, 1)
    with pytest.raises(SmspaceError, match="a whole number of levels"):
        lattice_walk(rng(), 3, 5, 1, 1, 5)
    with pytest.raises(SmspaceError, match="episode length"):
        continuous_walk(rng(), 3, 1, 0, 0.1)
