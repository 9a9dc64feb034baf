"""The JSON records written beside runs, studies and bench results, each declared once: its file,
the format this smspace writes and the formats it reads. Every one is encoded and decoded here:
bounded in size, plain JSON (no NaN, not nested without end), an object, of a format this smspace
knows. So a record of an unknown format, or a malformed one, is one line naming the file whichever
command reads it. (A dataset's manifest is versioned by its schema instead: lake/manifest.py.)

A record carries its format under "format"; those written before formats were recorded hold none
and are format 1, today's layout, so every earlier folder is still read.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from smspace.common.errors import SmspaceError
from smspace.lake.store import Store

FORMAT = "format"
MAX_BYTES = 4 << 20  # a record is small: a run's config, a study's terms, a bench result's sessions


class MalformedRecord(SmspaceError):
    """A record that is not one: too large, not plain JSON, not an object. `reason` says what,
    without the file, for a caller that words the refusal itself."""

    def __init__(self, where: str, reason: str | None = None):  # one argument: a message reworded by a caller
        super().__init__(where if reason is None else f"{where} {reason}")
        self.reason = reason or where


class UnknownFormat(SmspaceError):
    """A record of a format this smspace does not read (newer, or an older one it has retired)."""

    def __init__(self, message: str, found: Any = None):
        super().__init__(message)
        self.found = found


@dataclass(frozen=True)
class Record:
    file: str
    writes: int  # the format this smspace writes
    reads: tuple[int, ...]  # the formats it reads (1: records written before formats were recorded)
    max_bytes: int = MAX_BYTES

    def encode(self, body: Mapping[str, Any]) -> bytes:
        """The record's bytes: its format first, then `body` (which must not name one)."""
        if FORMAT in body:
            raise ValueError(f"{self.file}: the record's format is set here, not by its writer")
        return (json.dumps({FORMAT: self.writes, **body}, indent=1, allow_nan=False) + "\n").encode()

    def parse(self, data: bytes, where: str) -> Any:
        """The JSON value in `data`, bounded and plain; SmspaceError naming `where` otherwise."""
        if len(data) > self.max_bytes:
            raise MalformedRecord(where, f"is {len(data)} bytes; a {self.file} is at most {self.max_bytes}")
        try:
            return json.loads(data, parse_constant=_refuse_constant)
        except RecursionError:
            raise MalformedRecord(where, f"is nested too deep to be a {self.file}") from None
        except (ValueError, UnicodeDecodeError) as e:
            raise MalformedRecord(where, f"is not readable JSON ({e})") from None

    def format_of(self, raw: Any, where: str) -> int:
        """The format of a parsed record, refused unless this smspace reads it."""
        if not isinstance(raw, dict):
            raise MalformedRecord(where, "is not a JSON object")
        found = raw.get(FORMAT, 1)
        if found not in self.reads or isinstance(found, bool):
            known = ", ".join(map(str, self.reads))
            raise UnknownFormat(
                f"{where} is of format {found!r}; this smspace reads {self.file} of format {known} "
                "(written by another smspace version?)",
                found,
            )
        return found

    def decode(self, data: bytes, where: str) -> dict[str, Any]:
        """The record's body (its format checked and removed)."""
        return self._body(self.parse(data, where), where)

    def _body(self, raw: Any, where: str) -> dict[str, Any]:
        self.format_of(raw, where)
        return {k: v for k, v in raw.items() if k != FORMAT}

    def load(self, folder: Store) -> Any:
        """The JSON value of the record in `folder`, its size checked before it is read, its format
        not yet (FileNotFoundError if absent): for a reader that tells an older layout apart."""
        where = f"{folder.url}/{self.file}"
        size = folder.size(self.file)
        if size > self.max_bytes:
            raise MalformedRecord(where, f"is {size} bytes; a {self.file} is at most {self.max_bytes}")
        return self.parse(folder.read(self.file), where)

    def read(self, folder: Store) -> dict[str, Any]:
        """The record in `folder`, its format checked and removed (FileNotFoundError if absent)."""
        return self._body(self.load(folder), f"{folder.url}/{self.file}")

    def write(self, folder: Store, body: Mapping[str, Any]) -> None:
        folder.put(self.file, self.encode(body))


def _refuse_constant(word: str) -> None:
    raise ValueError(f"{word} is not a JSON number")


RUN_CONFIG = Record("config.json", 1, (1,))  # a run's TrainConfig (train/config.py)
RUN_STATUS = Record("status.json", 1, (1,))  # its state, step and message, rewritten as it trains
SWEEP_STUDY = Record("study.json", 1, (1,))  # a sweep folder's terms and ensembles (study/sweep.py)
STUDY_FILE = Record("study-file.json", 1, (1,))  # a study file as resolved (study/runner.py)
BENCH_RESULT = Record("bench.json", 1, (1,))  # a bench result: task, entry, datasets, sessions
BENCH_SCORES = Record("scores.json", 2, (2,))  # its scores and evidence; format 1 (a list) carried none

RECORDS = (RUN_CONFIG, RUN_STATUS, SWEEP_STUDY, STUDY_FILE, BENCH_RESULT, BENCH_SCORES)
