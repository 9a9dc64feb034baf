"""The invariants a walk's transitions keep (datagen/walks.py), checked as `validate` checks a
dataset: the first broken one is named, with the row it breaks at.

Within an episode the steps count 0, 1, 2, ... with no gap, and each step starts where the one
before it ended: the same motor state, sensor position, environment shift and sensation. The
environment keeps still where the mode says: everywhere in MM, within an episode in MME.
"""

from __future__ import annotations

import numpy as np

from smspace.lake.transitions import Transitions

CHAINED = (("m_t1", "m_t"), ("p_t1", "p_t"), ("shift_t1", "shift_t"), ("s_t1", "s_t"))


def _first(mask: np.ndarray) -> int | None:
    hits = np.flatnonzero(mask)
    return int(hits[0]) if len(hits) else None


def episode_problem(
    t: Transitions, episode: np.ndarray, step: np.ndarray, mode: str, first: int = 0, carried: bool = False
) -> str | None:
    """None if the rows are episodes in order that keep every invariant; else one line, naming
    the row as transition `first + row` (a shard's rows are numbered from its first index).
    `carried`: row 0 is the last row of the block before, checked there, so it need not start an
    episode; it is there so that the seam between blocks is checked."""
    problem = _problem(t, np.asarray(episode), np.asarray(step), mode, carried)
    if problem is None:
        return None
    row, line = problem
    return f"transition {first + row}: {line}"


def _problem(t: Transitions, episode: np.ndarray, step: np.ndarray, mode: str, carried: bool) -> tuple[int, str] | None:
    n = len(t)
    if episode.shape != (n,) or step.shape != (n,):
        return 0, f"{n} transitions with {episode.shape} episode and {step.shape} step indices"
    if n == 0:
        return None
    same = episode[1:] == episode[:-1]
    if (row := _first(episode[1:] < episode[:-1])) is not None:
        return row + 1, f"episode {episode[row + 1]} after episode {episode[row]} (episodes out of order)"
    starts = np.concatenate([[not carried], ~same])
    if (row := _first(starts & (step != 0))) is not None:
        return row, f"episode {episode[row]} starts at step {step[row]}, not 0"
    if (row := _first(same & (step[1:] != step[:-1] + 1))) is not None:
        return row + 1, f"episode {episode[row + 1]} goes from step {step[row]} to {step[row + 1]}"
    for ended, began in CHAINED:
        a, b = getattr(t, ended)[:-1], getattr(t, began)[1:]
        differs = np.any((a != b).reshape(n - 1, -1), axis=1)
        if (row := _first(same & differs)) is not None:
            return row + 1, f"{began} is not the {ended} of the step before (episode {episode[row + 1]})"
    moved = np.any(t.shift_t != t.shift_t1, axis=1)
    if mode in ("MM", "MME") and (row := _first(moved)) is not None:
        return row, f"the environment moves within a step in {mode}"
    if mode == "MM" and (row := _first(np.any(t.shift_t != t.shift_t[0], axis=1))) is not None:
        return row, "the environment moves between episodes in MM"
    return None
