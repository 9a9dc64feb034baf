"""How a dataset's agent explored: independent transitions (the paper's; a teleport between any
two) or walks (datagen/walks.py: episodes of `length` steps, each motor moving by about `step`).

A config records a walk as {"kind": "walk", "length": L, "step": x} and records nothing for
transitions, so every transitions dataset keeps the config hash it always had. A walk dataset's
id ends in "-walk", so a lake can hold both kinds of the same world and mode.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

KINDS = ("transitions", "walk")
WALK_SUFFIX = "-walk"
MAX_LENGTH = 1 << 20  # steps in one episode
WALK_LENGTH = 50  # steps per episode where none is given (smgen generate, smtrain sweep, a study file)
MAX_STEP = 4.0  # the grid's widest lattice step (5 levels); the arm's is a standard deviation ≤ 2


@dataclass(frozen=True)
class Exploration:
    kind: str = "transitions"
    length: int = 0  # steps per episode (walks only)
    step: float = 0.0  # per-step size: lattice levels (grid) or a standard deviation (arm)

    @property
    def walks(self) -> bool:
        return self.kind == "walk"

    @property
    def suffix(self) -> str:
        return WALK_SUFFIX if self.walks else ""

    def block_transitions(self, batch_size: int) -> int:
        """Transitions per stored batch: `batch_size`, or for walks the whole episodes that fit in
        it (at least one). The writer and the loader both read it from here."""
        return max(1, batch_size // self.length) * self.length if self.walks else batch_size

    def record(self) -> dict[str, Any] | None:
        """What a config records: nothing for transitions (their hashes stay what they were)."""
        return {"kind": self.kind, "length": self.length, "step": self.step} if self.walks else None

    def problem(self, transitions: int, shard_size: int) -> str | None:
        """Why this exploration cannot make a dataset of `transitions` in shards of `shard_size`."""
        if self.kind not in KINDS:
            return f"exploration {self.kind!r} is not one of {', '.join(KINDS)}"
        if not self.walks:
            return None
        if not (isinstance(self.length, int) and not isinstance(self.length, bool) and 1 <= self.length <= MAX_LENGTH):
            return f"walk length {self.length!r} is not a whole number of steps in 1..{MAX_LENGTH}"
        if not (isinstance(self.step, int | float) and not isinstance(self.step, bool) and 0 < self.step <= MAX_STEP):
            return f"walk step {self.step!r} is not in (0, {MAX_STEP}]"
        if shard_size % self.length or transitions % self.length:
            return (f"walks of {self.length} steps must fill the shards ({shard_size} transitions) and the "
                    f"dataset ({transitions}) whole: both must be multiples of the length")  # fmt: skip
        return None

    @classmethod
    def from_record(cls, raw: Any) -> Exploration:
        """The exploration a config recorded (None: transitions); a malformed one is a ValueError."""
        if raw is None:
            return cls()
        if not (isinstance(raw, dict) and set(raw) == {"kind", "length", "step"} and raw["kind"] == "walk"):
            raise ValueError(f"exploration record {raw!r} is not {{kind: walk, length, step}}")
        return cls("walk", raw["length"], raw["step"])


def stored_batch(config: dict[str, Any]) -> int:
    """Transitions per stored batch of a dataset, from its manifest's config."""
    return Exploration.from_record(config.get("exploration")).block_transitions(config["batch_size"])
