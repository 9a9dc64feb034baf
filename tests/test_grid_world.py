"""The discrete worlds against docs/MODEL.md §2.1 and 2.2."""

from __future__ import annotations

import math

import numpy as np

from smspace.datagen.setups import draw_transitions
from smspace.datagen.setups.grid import GridWorld, sensory_table


def test_motor_to_position_mapping_is_spec_2_1():
    w = GridWorld(0)
    assert w.motors.shape == (125, 3)
    # p = 4u - 2 with m = 2u³ - 1, i.e. p = 4·cbrt((m + 1) / 2) - 2
    expected = 4 * np.cbrt((w.motors[:, :2] + 1) / 2) - 2
    np.testing.assert_allclose(w.positions, expected, atol=1e-12)
    assert set(np.unique(w.motors)) == {-1.0, 2 * 0.25**3 - 1, 2 * 0.5**3 - 1, 2 * 0.75**3 - 1, 1.0}


def test_five_redundant_motor_states_per_position():
    w = GridWorld(0)
    cells, counts = np.unique(w.positions, axis=0, return_counts=True)
    assert len(cells) == 25 and set(counts) == {5}
    assert cells.min() == -2 and cells.max() == 2
    # the 5 states of one position differ only in the third motor
    same = w.motors[(w.positions == [1, -2]).all(1)]
    assert len(np.unique(same[:, :2], axis=0)) == 1 and len(np.unique(same[:, 2])) == 5


def test_sensory_formula_on_a_hand_computed_cell():
    rng = np.random.default_rng(123)
    table = sensory_table(np.random.default_rng(123))
    lam = rng.uniform(-2, 2, 12)  # component 0's draws, in the same order
    for k in range(0, 12, 2):
        if abs(lam[k]) < 0.25:
            lam[k] = math.copysign(0.25, lam[k])
    r, c = 3, 7
    x, y = c / 10, r / 10
    s = sum(math.cos(2 * math.pi * (round(lam[k]) * x + lam[k + 1])) / lam[k] for k in (0, 2, 4))
    s += sum(math.cos(2 * math.pi * (round(lam[k]) * y + lam[k + 1])) / lam[k] for k in (6, 8, 10))
    assert abs(table[r, c, 0] - s) < 1e-12


def test_torus_wrap_and_row_indexing():
    w = GridWorld(1)
    p = np.array([[2.0, -1.0]])
    base = w.sense(p, np.array([[0.0, 0.0]]))
    for shift in ([10.0, 0.0], [0.0, -10.0], [-20.0, 30.0]):
        np.testing.assert_array_equal(w.sense(p, np.array([shift])), base)
    # first coordinate indexes rows: cell (2, 9) after wrapping -1
    np.testing.assert_array_equal(base[0], w.table[2, 9].astype(np.float32))


def test_shift_ranges_and_mm_shift():
    w = GridWorld(0)
    shifts = w.sample_shifts(np.random.default_rng(0), 20000)
    assert set(np.unique(shifts)) == set(range(-10, 10))
    mm = draw_transitions(w, "MM", np.random.default_rng(0), 100)
    assert np.all(mm.shift_t == 5) and np.all(mm.shift_t1 == 5)


def test_mode_shift_rules():
    w = GridWorld(0)
    mme = draw_transitions(w, "MME", np.random.default_rng(1), 5000)
    assert np.array_equal(mme.shift_t, mme.shift_t1) and len(np.unique(mme.shift_t, axis=0)) > 50
    mem = draw_transitions(w, "MEM", np.random.default_rng(1), 5000)
    assert np.mean(np.all(mem.shift_t == mem.shift_t1, axis=1)) < 0.01
    # the sensation is the table at (p + shift) mod 10
    cell = np.mod((mem.p_t + mem.shift_t).astype(int), 10)
    np.testing.assert_array_equal(mem.s_t, w.table[cell[:, 0], cell[:, 1]].astype(np.float32))


def test_grid6_is_spec_2_2():
    w = GridWorld(5, n_motor=6)
    assert w.motors.shape == (15625, 6)
    np.testing.assert_allclose(w.motors.min(0), -1)
    np.testing.assert_allclose(w.motors.max(0), 1)
    cells, counts = np.unique(w.positions, axis=0, return_counts=True)
    assert len(cells) == 25 and set(counts) == {625}
    assert len(np.unique(w.motors, axis=0)) == 15625  # the mixing keeps every state distinct
    # the world and its sensory table come from the seed; grid and grid6 of one seed share the table
    np.testing.assert_array_equal(w.table, GridWorld(5).table)
    assert not np.array_equal(w.table, GridWorld(6).table)
