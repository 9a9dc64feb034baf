"""metrics/significance.py: the interval covers what it claims, the paired test is the t-test on
the differences, Holm's correction stops at the first comparison it keeps, and every draw comes
from the recorded seed."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from smspace.metrics.significance import bootstrap_interval, holm, paired_p, seed_of


def test_the_interval_is_drawn_from_its_seed_and_brackets_the_mean():
    x = [0.31, 0.29, 0.35, 0.4, 0.22, 0.3]
    first = bootstrap_interval(x, seed_of(0, "arm", "MM", "d_metric", "sensorimotor"))
    assert first == bootstrap_interval(x, seed_of(0, "arm", "MM", "d_metric", "sensorimotor"))
    few = [bootstrap_interval(x, seed_of(base, "arm", "MM"), resamples=40) for base in (0, 1)]
    assert few[0] != few[1]  # another seed, other resamples
    assert first[0] < float(np.mean(x)) < first[1] and min(x) <= first[0] and first[1] <= max(x)
    assert bootstrap_interval([2.5, 2.5, 2.5], 7) == (2.5, 2.5)
    assert bootstrap_interval([1.0], 7) is None
    with pytest.raises(ValueError):
        bootstrap_interval([1.0, float("nan")], 7)


def test_the_95_percent_interval_covers_the_true_mean_about_as_often_as_it_says():
    """200 samples of 10 worlds: the percentile bootstrap under-covers a little at n = 10 (about
    0.91 in theory); far below that, or always covering, would be a wrong interval."""
    rng = np.random.default_rng(11)
    covered = 0
    for trial in range(200):
        low, high = bootstrap_interval(rng.normal(3.0, 0.5, size=10), seed_of(5, str(trial)), resamples=2000)
        covered += low <= 3.0 <= high
    assert 0.84 <= covered / 200 <= 0.98, covered


def test_the_paired_test_is_the_t_test_of_the_differences():
    a, b = np.array([0.2, 0.25, 0.31, 0.18, 0.22, 0.27]), np.array([0.24, 0.26, 0.36, 0.2, 0.29, 0.28])
    assert paired_p(a, b) == pytest.approx(stats.ttest_rel(a, b).pvalue, rel=1e-12)
    assert paired_p(a, b) < 0.05 and paired_p(a, a[::-1]) > 0.5  # a shift on every world; a shuffle
    assert paired_p(a, a + 0.1) < 1e-10 and paired_p([1.0, 2.0, 3.0], [2.0, 3.0, 4.0]) == 0.0
    assert paired_p(a, a) == 1.0 and paired_p([1.0], [2.0]) is None


def test_holm_rejects_in_order_of_p_and_keeps_everything_after_the_first_it_keeps():
    p = {"a": 0.01, "b": 0.04, "c": 0.03, "d": 0.005}
    assert holm(p) == {"d": True, "a": True, "c": False, "b": False}  # 0.03 > 0.05/2 stops it
    assert holm({"a": 0.04}) == {"a": True} and holm({"a": 0.04, "b": 0.9}) == {"a": False, "b": False}
    assert holm({}) == {}


def _cells(entry: str, values: list[float], score: str = "d_metric") -> dict:
    return {"suite": "s", "task": "grid", "mode": "MM", "score": score, "entry": entry, "mean": float(np.mean(values)),
            "worlds": list(range(len(values))), "values": values}  # fmt: skip


def test_a_table_marks_the_best_the_floor_and_what_cannot_be_told_apart_from_each():
    from smspace.bench import differences

    rng = np.random.default_rng(3)
    world = rng.normal(0.3, 0.05, size=10)  # what every entry shares: some worlds are harder
    table = [
        _cells("good", list(world)),
        _cells("as-good", list(world + rng.normal(0.002, 0.004, size=10))),  # within noise of the best
        _cells("worse", list(world + 0.05 + rng.normal(0, 0.004, size=10))),
        _cells("random-encoder", list(world + 0.2 + rng.normal(0, 0.004, size=10))),
        _cells("as-bad", list(world + 0.2 + rng.normal(0.001, 0.004, size=10))),
    ]
    differences.mark(table, {"random-encoder"})
    shown = {c["entry"]: differences.marks(c) for c in table}
    assert shown == {"good": "best", "as-good": "≈best", "worse": "", "random-encoder": "floor", "as-bad": "≈floor"}
    for cell in table:  # what the marks follow from is stored beside them, and is recomputed here
        assert cell["ci"] == list(
            bootstrap_interval(cell["values"], seed_of(0, "s", "grid", "MM", "d_metric", cell["entry"]))
        )
        if cell["entry"] != "good":
            assert cell["vs_best"]["p"] == paired_p(cell["values"], table[0]["values"])
    direction_free = [_cells(e, c["values"], "local_dim") for e, c in zip(shown, table, strict=True)]
    differences.mark(direction_free, {"random-encoder"})
    assert all(c["vs_best"] is None and not c["is_best"] for c in direction_free)  # no best without a direction
    assert [differences.marks(c) for c in direction_free] == ["", "", "", "floor", "≈floor"]
    one_world = [_cells("good", [0.1]), _cells("random-encoder", [0.5])]
    differences.mark(one_world, {"random-encoder"})
    assert one_world[0]["vs_floor"]["real"] is None and differences.marks(one_world[0]) == "best ≈floor"
