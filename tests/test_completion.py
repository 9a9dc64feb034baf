"""Shell completion (common/completion.py through click): what bash is offered on Tab."""

from __future__ import annotations

import pytest

from .conftest import run_cmd


def offered(program: str, words: str, env: dict | None = None) -> list[str]:
    """What `program` offers for the last word of `words`, as bash's completion function asks it."""
    parts = words.split(" ")
    variables = {
        "COMP_WORDS": words,
        "COMP_CWORD": str(len(parts) - 1),
        f"_{program.upper()}_COMPLETE": "bash_complete",
    }
    result = run_cmd(program, timeout=60, env=variables | (env or {}))
    assert result.returncode == 0, result.stderr
    return [line.split(",", 1)[1] for line in result.stdout.splitlines() if line.startswith("plain,")]


def test_modes_setups_and_devices_are_offered():
    assert offered("smgen", "smgen generate --mode M") == ["MEM", "MM", "MME"]
    assert offered("smgen", "smgen generate --mode MEM,M") == ["MEM,MM", "MEM,MME"]
    assert offered("smgen", "smgen generate --mode a") == ["all"]
    assert offered("smtrain", "smtrain sweep --modes MM,") == ["MM,MEM", "MM,MME"]
    assert {"grid", "grid6", "arm", "arm6"} <= set(offered("smgen", "smgen generate --setup "))
    assert offered("smtrain", "smtrain sweep --setup gri") == ["grid", "grid6"]
    assert offered("smtrain", "smtrain fit --device c")[:2] == ["cpu", "cuda"]


def test_dataset_ids_of_the_named_lake_are_offered(grid_lake, tmp_path):
    ids = ["grid-seed3-MEM", "grid-seed3-MM", "grid-seed3-MME"]
    assert offered("smgen", f"smgen info --lake {grid_lake} grid-seed3-M") == ids
    assert offered("smgen", f"smgen validate --lake {grid_lake} grid-seed3-MME ") == ids
    assert offered("smtrain", f"smtrain fit --lake {grid_lake} grid-seed3-MME") == ["grid-seed3-MME"]
    assert offered("smtrain", "smtrain fit grid", env={"SMSPACE_LAKE": str(grid_lake)}) == ids
    assert offered("smgen", f"smgen info --lake {tmp_path / 'none'} g") == []  # no lake: nothing, no error


@pytest.mark.parametrize("shell", ["bash", "zsh", "fish"])
def test_the_completion_scripts_are_produced(shell):
    for program in ("smgen", "smtrain"):
        result = run_cmd(program, env={f"_{program.upper()}_COMPLETE": f"{shell}_source"})
        assert result.returncode == 0 and f"_{program.upper()}_COMPLETE" in result.stdout
