"""The numbers a dataset request holds (worlds, the first world's seed, transitions, shard size),
each declared once with its bounds, and one `coerce` that reads a flag's, a study file's or a
Python caller's value into it: `smgen generate`, `smtrain sweep`, study files and the API refuse
one bad number in the same words, naming it as its writer spelled it (`--transitions`,
`study.transitions`, `transitions`). The bounds themselves are the manifest's (lake/manifest.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from smspace.common.errors import SmspaceError
from smspace.lake.manifest import MAX_SHARD_SIZE, MAX_TRANSITIONS, MAX_WORLDS, SEED_MAX


@dataclass(frozen=True)
class Bounded:
    """An integer in low..high; `beyond`: what the upper bound is, as a refusal says it."""

    low: int
    high: int
    beyond: str

    def problem(self, value: Any) -> str | None:
        """Why `value` is not one (None: it is), without its name."""
        if not isinstance(value, int) or isinstance(value, bool):
            return f"must be an integer, got {value!r}"
        if value < self.low:
            return f"must be {'positive' if self.low == 1 else f'at least {self.low}'}, got {value}"
        if value > self.high:
            return f"{value} is more than {self.beyond} ({self.high})"
        return None

    def coerce(self, value: Any, name: str) -> int:
        problem = self.problem(value)
        if problem is not None:
            raise SmspaceError(f"{name} {problem}")
        return value


WORLDS = Bounded(1, MAX_WORLDS, "one command plans (the plan of every dataset is held in memory)")
SEED = Bounded(0, SEED_MAX, "a world seed may be (an int64 in the catalog)")
TRANSITIONS = Bounded(1, MAX_TRANSITIONS, "a dataset may hold")
SHARD_SIZE = Bounded(1, MAX_SHARD_SIZE, "a worker holds in memory")


def world_seeds_problem(seed: int, worlds: int) -> str | None:
    """The worlds' seeds are seed .. seed + worlds - 1, and the last must still be a seed."""
    if seed + worlds - 1 > SEED_MAX:
        return f"{seed} with {worlds} worlds passes the largest world seed, {SEED_MAX}"
    return None


def world_seeds(seed: Any, worlds: Any, seed_name: str = "seed", worlds_name: str = "worlds") -> range:
    """The seeds of a request's worlds, every number checked."""
    seed, worlds = SEED.coerce(seed, seed_name), WORLDS.coerce(worlds, worlds_name)
    problem = world_seeds_problem(seed, worlds)
    if problem is not None:
        raise SmspaceError(f"{seed_name} {problem}")
    return range(seed, seed + worlds)
