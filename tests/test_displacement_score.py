"""The displacement score (metrics/displacement.py) on a generated grid world's positions: a
representation of the move scores best, one of where the move ends (the posture score's view)
or a random one scores worse; pairs come from the seed alone."""

from __future__ import annotations

import numpy as np
import pytest

from smspace.datagen.setups.grid import GridWorld
from smspace.metrics.displacement import displacement_pairs, displacement_scores

pytestmark = pytest.mark.numerical  # float64 sums over pairs: any CPU kind


def test_pairs_are_seeded_distinct_and_cover_the_states():
    a, b = displacement_pairs(50, 4000, seed=3)
    a2, b2 = displacement_pairs(50, 4000, seed=3)
    np.testing.assert_array_equal(a, a2)
    np.testing.assert_array_equal(b, b2)
    assert not np.any(a == b)
    assert set(a) == set(b) == set(range(50))
    other, _ = displacement_pairs(50, 4000, seed=4)
    assert not np.array_equal(a, other)


def test_the_move_scores_better_than_where_it_ends_or_noise():
    p = GridWorld(0).positions
    a, b = displacement_pairs(len(p), 600, seed=0)
    mix = np.array([[0.7, -1.1, 0.2], [0.4, 0.9, -1.5]])
    move = displacement_scores((p[b] - p[a]) @ mix + 2.0, p, a, b)
    assert move.d_metric < 1e-6  # an affine image of the displacement is exact
    end = displacement_scores(p[b] @ mix, p, a, b)
    noise = displacement_scores(np.random.default_rng(0).normal(size=(len(a), 3)), p, a, b)
    assert end.d_metric > 10 * move.d_metric + 0.02
    assert noise.d_metric > end.d_metric and noise.d_topo > move.d_topo


def test_bad_input_is_named():
    p = GridWorld(0).positions
    a, b = displacement_pairs(len(p), 10)
    with pytest.raises(ValueError, match="10 starts"):
        displacement_scores(np.zeros((9, 3)), p, a, b)
    with pytest.raises(ValueError, match="two states"):
        displacement_pairs(1)
