"""lake/records.py: every JSON record smspace writes carries its format and is read through one
module. Records of the layout before formats (no "format" key) are still read; another format, or
a record that is not one, is one line naming the file."""

from __future__ import annotations

import json
import re

import pytest

from smspace.lake.records import FORMAT, RECORDS, MalformedRecord, UnknownFormat

from .conftest import failed_in_one_line, run_cmd

STUDY = """
[study]
setup = "grid"
modes = ["MM"]
worlds = 1
seed = 3
transitions = 3000

[train]
steps = 40
eval_every = 20
batch_size = 50
n_h = 3
"""


@pytest.mark.parametrize("record", RECORDS, ids=lambda r: r.file)
def test_every_record_carries_its_format_and_refuses_what_it_cannot_read(record):
    body = {"steps": 40, "name": "x"}
    data = record.encode(body)
    assert json.loads(data)[FORMAT] == record.writes and record.decode(data, "here") == body
    if 1 in record.reads:  # written before formats were recorded
        assert record.decode(json.dumps(body).encode(), "here") == body
    else:
        with pytest.raises(UnknownFormat, match=r"^here is of format 1; "):
            record.decode(json.dumps(body).encode(), "here")
    for found in (99, True, "1", None):
        with pytest.raises(UnknownFormat, match=rf"^here is of format {found!r}; this smspace reads {record.file}"):
            record.decode(json.dumps({FORMAT: found, **body}).encode(), "here")
    for data, said in [(b"[1]", "is not a JSON object"), (b'{"a": NaN}', "is not readable JSON (NaN is not"),
                       (b"{not", "is not readable JSON"), (b"[" * 100_000, "is nested too deep"),
                       (b" " * (record.max_bytes + 1), f"is {record.max_bytes + 1} bytes; a ")]:  # fmt: skip
        with pytest.raises(MalformedRecord, match="^" + re.escape(f"here {said}")):
            record.decode(data, "here")
    with pytest.raises(ValueError):
        record.encode({FORMAT: 7})  # a writer never sets the format itself


def test_runs_and_studies_of_the_layout_before_formats_are_read_and_another_format_refused(tmp_path):
    study, out, lake = tmp_path / "s.toml", tmp_path / "runs", tmp_path / "lake"
    study.write_text(STUDY)
    first = run_cmd("smtrain", "sweep", study, "--out", out, "--lake", lake, "--workers", 1, timeout=600)
    assert first.returncode == 0, first.stderr
    run = next(p.parent for p in out.glob("*/config.json"))
    records = [run / "config.json", run / "status.json", out / "study.json", out / "study-file.json"]
    for path in records:
        raw = json.loads(path.read_text())
        assert raw.pop(FORMAT) == 1, path
        path.write_text(json.dumps(raw, indent=1))  # as the smspace before formats wrote it
    again = run_cmd("smtrain", "sweep", study, "--out", out, "--lake", lake, "--workers", 1, timeout=600)
    assert again.returncode == 0 and "changed" not in again.stderr, again.stderr
    listed = run_cmd("smtrain", "ls", "--runs", out)
    assert listed.returncode == 0 and run.name in listed.stdout and "finished" in listed.stdout, listed
    longer = run_cmd("smtrain", "fit", "--resume", run, "--steps", 60, timeout=600)
    assert longer.returncode == 0, longer.stderr
    assert json.loads((run / "config.json").read_text())[FORMAT] == 1  # rewritten in today's format
    for path in records:
        raw = json.loads(path.read_text())
        path.write_text(json.dumps(raw | {FORMAT: 99}))
        if path.name in ("config.json", "status.json"):
            said = run_cmd("smtrain", "info", run)
        else:
            said = run_cmd("smtrain", "sweep", study, "--out", out, "--lake", lake, "--workers", 1)
        line = failed_in_one_line(said, "smtrain")
        assert f"{path} is of format 99; this smspace reads {path.name} of format 1" in line, line
        path.write_text(json.dumps(raw))


def test_bench_records_of_earlier_smspaces_are_typed_and_written_back_unchanged(tmp_path):
    """bench.json as the smspace of docs/bench/results wrote it (its sessions carry no outcome):
    read as a typed record, each session ended where its wall time is known, and written back it
    says the same; a field of the wrong type is one line naming the file."""
    from pathlib import Path

    from smspace.bench.result import BenchRecord
    from smspace.common.errors import SmspaceError
    from smspace.lake.store import open_store

    results = sorted((Path(__file__).resolve().parents[1] / "docs/bench/results").rglob("bench.json"))
    assert len(results) >= 30
    for path in results:
        raw = json.loads(path.read_text())
        record = BenchRecord.parse(raw, str(path))
        assert record.suite == raw["suite"] and len(record.sessions) == len(raw["sessions"])
        assert all(s.outcome == ("ended" if s.wall_s is not None else None) for s in record.sessions)
        folder = open_store(str(tmp_path / path.parent.name))
        folder.make()
        record.write(folder)
        again = BenchRecord.read(folder)
        assert again == record and again.terms() == {k: raw[k] for k in again.terms()}
        written = json.loads((tmp_path / path.parent.name / "bench.json").read_text())
        for before, after in zip(raw["sessions"], written["sessions"], strict=True):
            assert {k: v for k, v in after.items() if k != "outcome"} == before
    killed = {"sessions": [{"wall_s": None, "outcome": "ended"}]}
    for change, said in [({"version": "2"}, "version is '2', not a int"), ({"workers": 0}, "workers is 0"),
                         (killed, "session 0 has outcome 'ended' with wall_s None"),
                         ({"datasets": {"a": 1}}, "datasets are not dataset ids")]:  # fmt: skip
        with pytest.raises(SmspaceError, match="^" + re.escape(f"here: {said}")):
            BenchRecord.parse(json.loads(results[0].read_text()) | change, "here")


def test_a_run_status_is_typed_and_every_malformed_field_is_one_line_naming_the_file():
    """status.json as train/status.py reads it: written back it says the same; a "running" status
    of a process gone from this host reads "stale"; a field of the wrong type or out of its bounds,
    or one it does not know, is refused naming the file and the field."""
    import socket

    from smspace.common.errors import SmspaceError
    from smspace.train.status import RunStatus

    finished = RunStatus("finished", 40, "done", "abc")
    assert RunStatus.decode(finished.encode(), "here") == finished
    assert RunStatus.decode(b'{"state": "failed", "step": 3, "message": ""}', "here").run_id is None  # older
    dead = RunStatus("running", 20, "", "abc", pid=2**22 + 12345, host=socket.gethostname())
    assert RunStatus.decode(dead.encode(), "here").as_seen_here().state == "stale"
    elsewhere = RunStatus("running", 20, "", "abc", pid=1, host="another-host")
    assert elsewhere.as_seen_here() == elsewhere  # another host's process cannot be checked from here
    base = json.loads(finished.encode())
    for change, said in [({"step": "x"}, "step is 'x'"), ({"step": True}, "step is True"),
                         ({"step": -1}, "step -1 is negative"), ({"state": "won"}, "state 'won' is none of"),
                         ({"pid": "7"}, "pid is '7', not a int"), ({"host": 3}, "host is 3, not a str"),
                         ({"message": "x" * 70_000}, "its message is 70000 characters"),
                         ({"colour": "red"}, "unknown field(s) colour")]:  # fmt: skip
        with pytest.raises(
            SmspaceError, match="^" + re.escape("here/status.json is unreadable (") + ".*" + re.escape(said)
        ):
            RunStatus.decode(json.dumps(base | change).encode(), "here/status.json")
