"""study.json, a sweep folder's record as a typed value: the terms every run of the study shares
(train/terms.py, rule 4) and the ensembles its runs first trained in (so that a re-run trains the
same groups whatever its flags say now). Read by the sweep, its dry run and the study runner
alike; a record edited by hand is one line naming the file, never a KeyError."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from smspace.common.errors import SmspaceError, one_line
from smspace.lake.records import SWEEP_STUDY, MalformedRecord
from smspace.lake.store import Store
from smspace.train.config import TrainConfig

STUDY = SWEEP_STUDY.file


@dataclass(frozen=True)
class SweepRecord:
    terms: dict[str, Any]
    ensembles: tuple[tuple[str, ...], ...] = ()

    @classmethod
    def read(cls, out: Store) -> SweepRecord | None:
        """The study.json of `out`, None if absent; a malformed one refused (--overwrite starts
        anew), one of another format refused as such (--overwrite would be the wrong advice)."""
        try:
            raw = SWEEP_STUDY.read(out)
        except FileNotFoundError:
            return None
        except MalformedRecord as e:
            raise SmspaceError(
                f"{out.url}/{STUDY} is unreadable ({e.reason}); pass --overwrite to start anew"
            ) from None
        try:
            return cls.from_json(raw)
        except (KeyError, TypeError, ValueError, SmspaceError) as e:
            raise SmspaceError(
                f"{out.url}/{STUDY} is unreadable ({one_line(e, with_type=True)}); pass --overwrite to start anew"
            ) from None

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> SweepRecord:
        unknown = sorted(set(raw) - {"terms", "ensembles"})
        if unknown:
            raise ValueError(f"unknown field(s) {', '.join(unknown)}")
        terms = raw.get("terms")
        if not isinstance(terms, dict):
            raise TypeError("terms is not a table of a study's terms")
        if not isinstance(terms.get("steps"), int) or isinstance(terms.get("steps"), bool):
            raise TypeError("terms.steps is not a number of steps")
        TrainConfig.from_dict({**terms, "dataset": ""})  # every term a value a run could have
        groups = raw.get("ensembles", [])
        if not isinstance(groups, list) or not all(
            isinstance(g, list) and all(isinstance(n, str) for n in g) for g in groups
        ):
            raise TypeError("ensembles is not a list of lists of run names")
        names = [n for g in groups for n in g]
        if len(names) != len(set(names)):
            raise ValueError("a run is listed in two ensembles")
        return cls(terms, tuple(tuple(g) for g in groups))

    def to_json(self) -> dict[str, Any]:
        return {"terms": self.terms, "ensembles": [list(g) for g in self.ensembles]}

    def write(self, out: Store) -> None:
        out.put(STUDY, SWEEP_STUDY.encode(self.to_json()))

    def with_ensembles(self, new: list[list[str]]) -> SweepRecord:
        """The record with `new` groups after those it holds (a group, once recorded, stays)."""
        return replace(self, ensembles=self.ensembles + tuple(tuple(g) for g in new))
