"""The exploration a config records (lake/exploration.py): transitions record nothing, so their
config hashes are what they always were; walks record their length and step, get their own id,
and must fill the shards whole."""

from __future__ import annotations

import pytest

from smspace.lake.exploration import Exploration


def test_transitions_record_nothing_and_walks_their_terms():
    assert Exploration().record() is None and Exploration().suffix == ""
    walk = Exploration("walk", 100, 1)
    assert walk.record() == {"kind": "walk", "length": 100, "step": 1} and walk.suffix == "-walk"
    assert Exploration.from_record(walk.record()) == walk
    assert Exploration.from_record(None) == Exploration()


@pytest.mark.parametrize(
    "exploration, named",
    [
        (Exploration("teleport"), "not one of transitions, walk"),
        (Exploration("walk", 0, 1), "walk length 0"),
        (Exploration("walk", True, 1), "walk length True"),
        (Exploration("walk", 100, 0), "walk step 0"),
        (Exploration("walk", 100, 9), "walk step 9"),
        (Exploration("walk", 300, 1), "multiples of the length"),
    ],
)
def test_bad_explorations_are_named(exploration, named):
    problem = exploration.problem(transitions=3000, shard_size=1000)
    assert problem is not None and named in problem


def test_a_good_walk_has_no_problem():
    assert Exploration("walk", 100, 0.05).problem(3000, 1000) is None


def test_a_malformed_record_is_refused():
    with pytest.raises(ValueError, match="is not"):
        Exploration.from_record({"kind": "walk", "length": 10})


def test_a_walk_config_has_its_own_id_and_hash_and_transitions_keep_theirs():
    from smspace.bench.suite import QUICK_GRID, datasets_hash
    from smspace.lake.manifest import GenConfig

    plain = GenConfig("grid", "MM", 0, 3000, 1000)
    walk = GenConfig("grid", "MM", 0, 3000, 1000, exploration=Exploration("walk", 100, 1).record())
    assert plain.dataset_id == "grid-seed0-MM" and walk.dataset_id == "grid-seed0-MM-walk"
    assert "exploration" not in plain.to_dict() and walk.to_dict()["exploration"]["length"] == 100
    assert plain.config_hash != walk.config_hash and walk.problem() is None
    assert GenConfig.from_record(walk.to_dict(), "here") == walk
    assert datasets_hash(QUICK_GRID.datasets()) == QUICK_GRID.datasets_hash  # transitions: as pinned
    misaligned = GenConfig("grid", "MM", 0, 3000, 1000, exploration=Exploration("walk", 300, 1).record())
    assert "multiples of the length" in misaligned.problem()
    with pytest.raises(Exception, match="exploration record"):
        GenConfig.from_record(plain.to_dict() | {"exploration": {"kind": "walk"}}, "here")
