"""D_topo and D_metric against a brute force over all pairs, and on known cases."""

from __future__ import annotations

import numpy as np
import pytest

import smspace.metrics.spatial as spatial
from smspace.datagen.setups.grid import GridWorld
from smspace.metrics import affine_projection, spatial_scores

pytestmark = pytest.mark.numerical  # float64 blockwise sums against a brute force: any CPU kind


def brute_force(h: np.ndarray, p: np.ndarray, alpha: float = 50.0) -> tuple[float, float]:
    """docs/MODEL.md §4 written literally: every pair i < j, distances in float64."""
    n = len(h)
    i, j = np.triu_indices(n, k=1)
    dh = np.linalg.norm(h[i] - h[j], axis=1)
    dp = np.linalg.norm(p[i] - p[j], axis=1)
    x = np.hstack([h, np.ones((n, 1))])
    coef = np.linalg.lstsq(x, p, rcond=None)[0]
    hh = x @ coef
    dhh = np.linalg.norm(hh[i] - hh[j], axis=1)
    topo = np.mean(dh / dh.max() * np.exp(-alpha * dp / dp.max()))
    metric = np.mean(np.abs(dhh - dp)) / dp.max()
    return topo, metric


@pytest.mark.parametrize("n_h", [2, 3, 25])
def test_matches_brute_force_on_small_sets(n_h, monkeypatch):
    monkeypatch.setattr(spatial, "BLOCK_ELEMENTS", 5000)  # many blocks, ragged last one
    rng = np.random.default_rng(n_h)
    p = GridWorld(0).positions
    h = rng.normal(size=(len(p), n_h))
    got = spatial_scores(h, p)
    topo, metric = brute_force(h, p)
    assert got.d_topo == pytest.approx(topo, rel=1e-5)
    assert got.d_metric == pytest.approx(metric, rel=1e-5)


def test_continuous_positions_and_trained_like_encodings():
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.5, 1.5, (300, 2))
    h = np.c_[np.tanh(p), p[:, :1] * p[:, 1:]] + rng.normal(0, 0.05, (300, 3))
    got = spatial_scores(h, p)
    topo, metric = brute_force(h, p)
    assert got.d_topo == pytest.approx(topo, rel=1e-5) and got.d_metric == pytest.approx(metric, rel=1e-5)


def test_affine_image_of_p_has_zero_metric_error():
    p = GridWorld(2, 6).positions
    a = np.array([[0.3, -1.2, 2.0], [1.1, 0.4, -0.7]])
    h = p @ a + np.array([5.0, -3.0, 0.25])
    scores = spatial_scores(h, p)
    assert scores.d_metric < 1e-6
    np.testing.assert_allclose(affine_projection(h, p), p, atol=1e-9)


def test_random_h_is_far_from_zero():
    p = GridWorld(0).positions
    h = np.random.default_rng(0).normal(size=(len(p), 3))
    scores = spatial_scores(h, p)
    assert scores.d_metric > 0.2 and scores.d_topo > 5e-3
    # and h = p is near-perfect topology (reference value ~3.4e-6, docs/MODEL.md §4)
    assert spatial_scores(np.c_[p, np.zeros(len(p))], p).d_topo < 1e-5


def test_d_metric_is_invariant_to_an_affine_transform_of_h():
    rng = np.random.default_rng(3)
    p = GridWorld(0).positions
    h = np.tanh(rng.normal(size=(len(p), 3)) + np.c_[p, p[:, :1]])
    a = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    transformed = h @ a + rng.normal(size=3)
    assert spatial_scores(transformed, p).d_metric == pytest.approx(spatial_scores(h, p).d_metric, rel=1e-5)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError):
        spatial_scores(np.zeros((1, 3)), np.zeros((1, 2)))
    with pytest.raises(ValueError):
        spatial_scores(np.zeros((4, 3)), np.ones((4, 2)))


def test_room_ambiguity_tells_distinctive_views_from_mirrored_ones():
    """smspace.metrics.ambiguity (scripts/arm_ambiguity.py, the ambiguity study) backs claims in
    docs/REPRODUCTION.md: its measures must separate a room whose views all differ from one whose
    views repeat across a mirror."""
    from smspace.metrics.ambiguity import view_ambiguity

    p = np.random.default_rng(0).uniform(-1.5, 1.5, size=(400, 2))
    waves = np.linspace(0.3, 1.0, 8)  # |w x| < pi/2: each feature is monotonic in x or in y
    distinct = np.concatenate([np.sin(waves * p[:, :1]), np.sin(waves * p[:, 1:])], axis=1)
    mirrored = np.concatenate([np.cos(waves * p[:, :1]), np.sin(waves * p[:, 1:])], axis=1)  # x and -x alike
    clear, ambiguous = view_ambiguity(p, distinct), view_ambiguity(p, mirrored)
    assert clear["far_lookalikes"] < 0.05 < ambiguous["far_lookalikes"]
    assert clear["lookalike_distance"] < 0.3 < ambiguous["lookalike_distance"]
    assert clear["image_geometry_d_metric"] < 0.05 < ambiguous["image_geometry_d_metric"]


def test_a_rank_deficient_h_is_fitted_without_amplifying_its_rounding():
    """A linear encoder of 2 motors into 3 dimensions gives an h of rank 2: float32 rounding made a
    third, thin direction onto which the fit projected p, and D_metric moved by 1 % between the
    same run alone and in an ensemble. Directions thinner than the rounding are left out."""
    rng = np.random.default_rng(3)
    p = GridWorld(0).positions
    m = rng.normal(size=(len(p), 2))
    h = m @ rng.normal(size=(2, 3)) + 0.5  # rank 2 in 3 dimensions
    exact = spatial_scores(h, p).d_metric
    for k in range(5):
        rounded = (h + rng.normal(size=h.shape) * 1e-7 * np.abs(h)).astype(np.float32)
        assert spatial_scores(rounded, p).d_metric == pytest.approx(exact, rel=1e-5), k
    assert spatial_scores(m, p).d_metric == pytest.approx(exact, rel=1e-9)  # the same span: the same fit


def test_two_nn_finds_the_dimension_of_the_manifold_not_of_the_space_it_lies_in():
    from smspace.metrics.dimension import two_nn_dimension

    rng = np.random.default_rng(3)
    for d, low, high in ((1, 0.9, 1.1), (2, 1.85, 2.2)):
        flat = rng.uniform(size=(2000, d)) @ rng.normal(size=(d, 8))  # embedded in 8 dimensions
        assert low < two_nn_dimension(flat) < high, d
    plane = rng.uniform(size=(500, 2)) @ rng.normal(size=(2, 3))
    repeated = np.vstack([plane, plane, plane[:100]])  # several motor states at one h say nothing more
    assert two_nn_dimension(repeated) == two_nn_dimension(plane)
    with pytest.raises(ValueError, match="3 distinct points"):
        two_nn_dimension(np.zeros((10, 3)))


def test_the_probe_scores_positions_on_states_it_was_not_fitted_on():
    from smspace.metrics.probe import probe_r2

    rng = np.random.default_rng(5)
    p = rng.uniform(-2, 2, size=(125, 2))
    encoded = np.hstack([p @ rng.normal(size=(2, 2)), np.zeros((125, 1))]) + 1e-3 * rng.normal(size=(125, 3))
    assert probe_r2(encoded, p) > 0.999
    wide_noise = rng.normal(size=(125, 25))  # 26 parameters fit 125 points in-sample, not held-out ones
    assert spatial_scores(wide_noise, p).d_metric < spatial_scores(rng.normal(size=(125, 3)), p).d_metric
    assert probe_r2(wide_noise, p) < 0.0
    assert probe_r2(encoded, p, seed=1) != probe_r2(encoded, p, seed=2)  # the folds come from the seed
    assert probe_r2(encoded, p, seed=1) == probe_r2(encoded, p, seed=1)
    with pytest.raises(ValueError, match="all positions coincide"):
        probe_r2(encoded, np.zeros((125, 2)))


def test_the_torus_probe_tells_a_learned_torus_from_a_learned_plane():
    """On a floor whose view repeats every metre over a 3 m working space, an h of p modulo the
    period predicts the torus and not the plane, an h of p the plane and not the torus; where the
    period is far wider than the space, the two agree."""
    from smspace.metrics.probe import on_the_torus, probe_r2, torus_probe_r2

    rng = np.random.default_rng(3)
    p = rng.uniform(-1.5, 1.5, size=(400, 2))
    torus = on_the_torus(p, 1.0) @ rng.normal(size=(4, 4))  # a learned torus, linearly mixed
    assert torus_probe_r2(torus, p, 1.0) > 0.999 and probe_r2(torus, p) < 0.1
    plane = p @ rng.normal(size=(2, 3))
    assert probe_r2(plane, p) > 0.999 and torus_probe_r2(plane, p, 1.0) < 0.1
    assert torus_probe_r2(plane, p, 24.0) > 0.98  # no repeat in reach: the torus is nearly the plane
    with pytest.raises(ValueError, match="a period is > 0"):
        torus_probe_r2(plane, p, 0.0)


def test_local_pca_reads_a_lattices_dimension_where_two_nn_diverges():
    """The bench's regular samplings are lattices (the grid's 5×5 positions, the arm's joint
    angles): there TwoNN's r₂ / r₁ is 1 and it diverges; local PCA counts the lattice's directions."""
    from smspace.metrics.dimension import local_pca_dimension, two_nn_dimension

    rng = np.random.default_rng(0)
    plane = np.stack(np.meshgrid(np.arange(5), np.arange(5)), -1).reshape(-1, 2).astype(float)
    cube = np.stack(np.meshgrid(*[np.arange(6)] * 3), -1).reshape(-1, 3).astype(float)
    assert two_nn_dimension(plane) == float("inf")
    assert local_pca_dimension(plane) == 2.0 and local_pca_dimension(plane @ rng.normal(size=(2, 3))) == 2.0
    assert local_pca_dimension(cube) == 3.0
    assert local_pca_dimension(np.linspace(0, 1, 50)[:, None] * np.array([[1.0, 2.0, 3.0]])) == 1.0
    scattered = rng.uniform(size=(800, 2)) @ rng.normal(size=(2, 5))  # a random sample: both agree
    assert 1.9 < local_pca_dimension(scattered) <= 2.0 and 1.8 < two_nn_dimension(scattered) < 2.2
    assert local_pca_dimension(np.repeat(plane, 3, axis=0)) == 2.0  # duplicates merged
    with pytest.raises(ValueError, match="3 distinct points"):
        local_pca_dimension(np.zeros((10, 3)))


def test_a_spread_over_worlds_is_the_sample_standard_deviation_and_none_for_one_world():
    """metrics/spread.py: the one summary `smtrain report` and the leaderboard give (ddof 1)."""
    from smspace.metrics.spread import Spread, along, as_cell

    spread = Spread.of([1.0, 2.0, 4.0])
    assert spread.mean == pytest.approx(7 / 3) and spread.std == pytest.approx(np.std([1, 2, 4], ddof=1))
    assert spread.count == 3 and as_cell(spread.mean, spread.std) == "2.33 ± 1.5"
    one = Spread.of([0.125])
    assert one.std is None and as_cell(one.mean, one.std) == "0.125"  # no "± 0" claiming a spread
    mean, std = along(np.array([[1.0, 2.0], [3.0, 6.0]]))
    assert mean.tolist() == [2.0, 4.0] and std == pytest.approx([np.sqrt(2), np.sqrt(8)])
    assert along(np.array([[1.0, 2.0]]))[1].tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="one or more values"):
        Spread.of([])


def test_groups_come_in_the_given_order_then_sorted_whatever_order_the_items_came_in():
    from smspace.metrics.spread import grouped

    items = [("MME", 1), ("x", 2), ("MM", 3), ("MME", 4), ("MEM", 5), ("a", 6)]
    for order in (items, items[::-1]):
        groups = grouped(order, lambda item: item[0], ("MEM", "MM", "MME"))
        assert list(groups) == ["MEM", "MM", "MME", "a", "x"]
        assert sorted(groups["MME"]) == [("MME", 1), ("MME", 4)]
    assert grouped(items, lambda item: item[0])["MME"] == [("MME", 1), ("MME", 4)]  # in the items' order
    assert list(grouped([], lambda item: item, ("MM",))) == []
