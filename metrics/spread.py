"""How scores are grouped and summarised over worlds (or runs), the one way `smtrain report` and
the leaderboard both do it. Groups: by a key (a study's terms, a mode), never pooled across keys.
Summary: the mean, the sample standard deviation (ddof 1: an estimate of
the spread of worlds the table's few were drawn from, not of those few alone), and how many there
were. One world has no spread: None, never a "± 0" that would claim one."""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

DDOF = 1
T = TypeVar("T")
K = TypeVar("K", bound=Hashable)


def grouped(items: Iterable[T], key: Callable[[T], K], order: Sequence[K] = ()) -> dict[K, list[T]]:
    """`items` by `key`, each group in the items' order: the keys of `order` first (the modes in
    the paper's order), then the others sorted by their text, so a table's rows never depend on
    the order the folders were listed in."""
    groups: dict[K, list[T]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    rest = sorted((k for k in groups if k not in order), key=str)
    return {k: groups[k] for k in [*(k for k in order if k in groups), *rest]}


@dataclass(frozen=True)
class Spread:
    mean: float
    std: float | None  # None for a single value
    count: int

    @classmethod
    def of(cls, values: Sequence[float] | np.ndarray) -> Spread:
        x = np.asarray(values, dtype=np.float64)
        if x.ndim != 1 or len(x) == 0:
            raise ValueError(f"a spread is over one or more values, not an array of shape {x.shape}")
        return cls(float(x.mean()), float(x.std(ddof=DDOF)) if len(x) > DDOF else None, len(x))


def as_cell(mean: float, std: float | None) -> str:
    """A spread as a table cell: mean ± std, three and two significant digits."""
    return f"{mean:.3g}" if std is None else f"{mean:.3g} ± {std:.2g}"


def along(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and sample std along the first axis (curves of several runs, step by step); the std is
    0 where there is one run, for a band that draws nothing."""
    x = np.asarray(values, dtype=np.float64)
    return x.mean(0), (x.std(0, ddof=DDOF) if len(x) > DDOF else np.zeros(x.shape[1:]))
