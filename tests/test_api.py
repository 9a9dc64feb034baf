"""The Python API: every example of docs/API.md runs, in order, as a reader would run it."""

from __future__ import annotations

import re
import shutil

import pytest

import smspace

from .conftest import ROOT, SAMPLES


def examples() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "API.md").read_text(), flags=re.S)


def test_the_examples_of_docs_api_run(tmp_path, monkeypatch):
    shutil.copytree(SAMPLES, tmp_path / "data" / "samples")
    monkeypatch.chdir(tmp_path)
    blocks = examples()
    assert len(blocks) >= 5
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "docs/API.md", "exec"), namespace)
    assert namespace["run"].config.extensions == [{"from_steps": 200, "to_steps": 300}]
    assert [row["step"] for row in namespace["run"].metrics()] == [0, 100, 200, 300]
    assert namespace["h"].shape == (125, 3)
    assert sorted(r.config.n_h for r in namespace["study_runs"]) == [2, 3]
    assert (tmp_path / "runs" / "tiny" / "n_h=2" / "grid-seed7-MM-nh2-seed7" / "tensorboard").is_dir()
    assert namespace["log"].seen == [0, 50, 100, "finished at 100"]
    assert [r.url for r in namespace["same_runs"]] == [r.url for r in namespace["study_runs"]]  # define_study
    assert [r.url.rsplit("/", 2)[-2] for r in namespace["found"]] == ["n_h=2", "n_h=3"]
    assert [r.url for r in smspace.find_runs("runs")] == sorted(r.url for r in smspace.find_runs("runs"))
    assert len(smspace.find_runs("runs")) > 2 and smspace.find_runs(tmp_path / "data") == []
    with pytest.raises(smspace.SmspaceError, match="is a file, not a folder of runs"):
        smspace.find_runs(namespace["study_runs"][0].url + "/config.json")


def test_what_is_public_is_named_and_loads():
    for name in smspace.__all__:
        assert getattr(smspace, name) is not None, name
    with pytest.raises(AttributeError):
        _ = smspace.no_such_name
    with pytest.raises(TypeError, match="unknown training fields"):
        smspace.fit("grid-seed0-MM", lake=SAMPLES, stepz=10)


def test_a_sink_of_ones_own_sees_each_evaluation_after_the_run_folder_committed_it(tmp_path):
    from smspace.train.run_dir import RunView

    out = tmp_path / "run"

    class Committed:
        def __init__(self):
            self.steps = []

        def on_evaluation(self, evaluation):
            assert RunView.open(out).checkpoint_step() == evaluation.step  # in the run before a logger sees it
            assert evaluation.h.shape == (125, 3) and evaluation.rows[-1]["step"] == evaluation.step
            self.steps.append(evaluation.step)
            if evaluation.step == 40:
                raise ValueError("the logger's server is down")

        def on_finish(self, step, message):
            self.steps.append("finished")

    sink = Committed()
    with pytest.raises(ValueError, match="server is down"):
        smspace.fit("grid-seed0-MM", lake=SAMPLES, out=out, steps=60, eval_every=20, sinks=[sink])
    assert sink.steps == [0, 20, 40]
    status = RunView.open(out).status()
    assert status.state == "failed" and "server is down" in status.message and status.step == 40
    resumed = smspace.resume(out, sinks=[])
    assert [row["step"] for row in resumed.metrics()] == [0, 20, 40, 60]


def test_a_run_a_user_opens_only_reads(tmp_path):
    """smspace.Run hands users what ls, info, report and view read, and no method that writes:
    a run folder is written by the process training it alone."""
    out = tmp_path / "run"
    run = smspace.fit("grid-seed0-MM", lake=SAMPLES, out=out, steps=20, eval_every=10)
    opened = smspace.open_run(out)
    writes = ("write", "set_", "save", "claim", "release", "create", "truncate", "roll_back", "record_")
    assert not [name for name in dir(opened) if name.lstrip("_").startswith(writes)]
    assert opened.summary() | {"elapsed_s": None} == run.summary() | {"elapsed_s": None}
    assert opened.summary()["state"] == "finished" and opened.summary()["step"] == 20
    h, p = opened.embeddings(20)
    assert h.shape == (125, 3) and len(p) == 125 and opened.load_checkpoint()["step"] == 20
