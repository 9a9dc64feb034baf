"""status.json, a run's state as a typed record: rewritten as the run trains, read by `ls`, `info`,
`report` and every writer that marks how a run stopped. Parsed field by field (types and bounds),
so a tampered or foreign status is one line naming the file, never a KeyError three calls later.
"""

from __future__ import annotations

import socket
from dataclasses import asdict, dataclass, replace
from typing import Any

from smspace.common.errors import SmspaceError
from smspace.common.processes import alive
from smspace.lake.records import RUN_STATUS

STATES = ("created", "running", "finished", "failed", "interrupted")  # what a writer records
STALE = "stale"  # what a reader says of a "running" run whose process is gone from this host
MAX_MESSAGE = 64 << 10


@dataclass(frozen=True)
class RunStatus:
    state: str
    step: int
    message: str = ""
    run_id: str | None = None
    pid: int | None = None  # who runs it, recorded while "running"
    host: str | None = None

    @classmethod
    def created(cls) -> RunStatus:
        """The status of a run folder that has none yet."""
        return cls("created", 0)

    @classmethod
    def decode(cls, data: bytes, where: str) -> RunStatus:
        raw = RUN_STATUS.decode(data, where)
        try:
            return cls.from_json(raw)
        except (TypeError, ValueError) as e:
            raise SmspaceError(f"{where} is unreadable ({e})") from None

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> RunStatus:
        """Every field typed and bounded (ValueError/TypeError saying which); unknown keys refused."""
        unknown = sorted(set(raw) - {f for f in cls.__dataclass_fields__})
        if unknown:
            raise ValueError(f"unknown field(s) {', '.join(unknown)}")
        for name, kind in (("state", str), ("step", int), ("message", str)):
            if not isinstance(raw.get(name), kind) or isinstance(raw.get(name), bool):
                raise TypeError(f"state, step and message must be recorded; {name} is {raw.get(name)!r}")
        if raw["state"] not in (*STATES, STALE):
            raise ValueError(f"state {raw['state'][:40]!r} is none of {', '.join(STATES)}")
        if raw["step"] < 0:
            raise ValueError(f"step {raw['step']} is negative")
        if len(raw["message"]) > MAX_MESSAGE:
            raise ValueError(f"its message is {len(raw['message'])} characters, more than {MAX_MESSAGE}")
        for name, kind in (("run_id", str), ("pid", int), ("host", str)):
            value = raw.get(name)
            if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
                raise TypeError(f"{name} is {value!r}, not a {kind.__name__}")
        return cls(**raw)

    def encode(self) -> bytes:
        return RUN_STATUS.encode({k: v for k, v in asdict(self).items() if v is not None or k == "run_id"})

    def as_seen_here(self) -> RunStatus:
        """ "running" becomes "stale" when its process is gone from this host (another host's run
        cannot be checked from here and keeps its state)."""
        if self.state == "running" and self.host == socket.gethostname() and not alive(self.pid):
            return replace(self, state=STALE, message="its process is gone; resume with --resume")
        return self
