"""Which differences in a table are real: a confidence interval for a mean over worlds, and a
paired test between two entries scored on the same worlds, corrected for the number of
comparisons a table makes (docs/BENCHMARK.md, "Which differences are real").

- The interval is a percentile bootstrap of the mean (`RESAMPLES` resamples of the worlds), drawn
  from a seed the caller records, so the same scores give the same bytes.
- The test is a paired t-test on the per-world differences. A rank or sign-flip test would assume
  less, but its smallest two-sided p is 2/2^n: 1/32 for the 6 worlds of an arm task, which no
  threshold corrected for eight comparisons (0.05/8) accepts, so it could never tell anything apart.
- The correction is Holm's step-down over the comparisons of one table cell group (every entry
  against the best, or against the floor): it holds the family-wise error at `ALPHA` whatever the
  comparisons' dependence, and rejects at least what Bonferroni does.
"""

from __future__ import annotations

import hashlib
from collections.abc import Hashable, Mapping, Sequence
from typing import TypeVar

import numpy as np
from scipy import stats

LEVEL = 0.95
ALPHA = 0.05
RESAMPLES = 10_000
K = TypeVar("K", bound=Hashable)


def seed_of(base: int, *parts: str) -> int:
    """A seed for one cell's draws, from the recorded `base` and the cell's names: the same cell
    always draws the same resamples, whatever else the table holds or its order."""
    digest = hashlib.sha256("\x1f".join([str(base), *parts]).encode()).digest()
    return int.from_bytes(digest[:8], "little")


def bootstrap_interval(
    values: Sequence[float] | np.ndarray, seed: int, level: float = LEVEL, resamples: int = RESAMPLES
) -> tuple[float, float] | None:
    """The `level` percentile-bootstrap interval of the mean of `values`; None for fewer than two
    (one world has no spread to resample)."""
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError("an interval is over finite values in one dimension")
    if len(x) < 2:
        return None
    rng = np.random.Generator(np.random.PCG64(seed))
    means = x[rng.integers(0, len(x), size=(resamples, len(x)))].mean(axis=1)
    low, high = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def paired_p(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> float | None:
    """The two-sided p of a paired t-test of a against b (the same worlds, in the same order); None
    for fewer than two pairs. Differences all equal: 1 when they are zero, else 0 (a constant
    shift on every world is as real as a difference gets; the t statistic would be infinite)."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    if d.ndim != 1 or not np.all(np.isfinite(d)):
        raise ValueError("a paired test is over finite pairs in one dimension")
    if len(d) < 2:
        return None
    if np.ptp(d) == 0.0:
        return 1.0 if d[0] == 0.0 else 0.0
    t = d.mean() / (d.std(ddof=1) / np.sqrt(len(d)))
    return float(min(1.0, 2.0 * stats.t.sf(abs(t), df=len(d) - 1)))


def holm(pvalues: Mapping[K, float], alpha: float = ALPHA) -> dict[K, bool]:
    """Which comparisons Holm's step-down rejects at family-wise level `alpha`: sorted by p, the
    i-th (from 0) of m is rejected while p <= alpha / (m - i); every later one is kept."""
    order = sorted(pvalues, key=lambda k: (pvalues[k], str(k)))
    m, rejected, going = len(order), {}, True
    for i, key in enumerate(order):
        going = going and pvalues[key] <= alpha / (m - i)
        rejected[key] = going
    return rejected
