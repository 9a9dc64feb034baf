"""A study as a file: which datasets, which training terms, and a grid over any training field.

    [study]                       # what the runs train on
    setup = "grid"                # a built-in or registered setup
    modes = ["MEM", "MM", "MME"]  # or "all"
    worlds = 10                   # world seeds seed .. seed + worlds - 1
    seed = 0
    transitions = 150000          # optional: the setup's default
    exploration = "walk"          # optional: "transitions" (the default) or walks (docs/MODEL.md)
    walk_length = 50              # walks only: steps per episode [50]
    walk_step = 1.0               # walks only: per step, the setup's unit [the setup's]
    [train]                       # any field of `smtrain fit`'s flags, by its config name
    steps = 100000
    [grid]                        # optional: one sub-study per combination of these values
    n_h = [3, 25]                 # (`setup` may be a key too: one sub-study per setup)
    [pairs]                       # optional: values taken together, not crossed (equal lengths)
    model = ["sensorimotor", "shallow"]
    model_params = [{}, {width = 48}]
    [run]                         # how it runs, not what it computes
    workers = 2

On the command line, `section.key=value` overrides (Hydra's habit) apply on top of the file:
`smtrain sweep study.toml train.steps=2000 grid.n_h=[3,5]`; a value is TOML (a bare word is a
string), and the resolved study records them (`overrides`).

Read with the standard library (tomllib) and checked here, in one place: every error is one line
naming the file and the key. A study's resolved file is recorded in its output folder
(`study-file.json`, beside a copy of the file) so that a later run of a changed file is told what
changed (`changes`), and each combination of the grid is an ordinary sweep folder with its own
study.json (train/terms.py), which refuses what may not change.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import MISSING, Field, asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from smspace.common.cli import EXECUTORS, MAX_ENSEMBLE, MAX_WORKERS
from smspace.common.differing import described
from smspace.common.errors import SmspaceError
from smspace.lake.bounds import SEED, TRANSITIONS, WORLDS, Bounded, world_seeds_problem
from smspace.lake.exploration import KINDS, MAX_LENGTH, MAX_STEP, WALK_LENGTH, Exploration
from smspace.lake.records import STUDY_FILE
from smspace.lake.transitions import MODES
from smspace.train.config import TrainConfig, finite_positive, flag_fields
from smspace.train.terms import PER_RUN

RECORD = STUDY_FILE.file  # the resolved study, in its output folder
SOURCE = "study-file.toml"  # the file as it was given
FLAGS = "the flags of smtrain sweep"  # where a study given by flags came from
SECTIONS = ("study", "train", "grid", "pairs", "run")
# [run] keys and their bounds: the same as the flags' (a million workers started a process per run)
RUN_KEYS = {"workers": (1, MAX_WORKERS), "gen_workers": (1, MAX_WORKERS), "max_ensemble": (1, MAX_ENSEMBLE),
            "executor": None}  # fmt: skip
TABLES = ("train", "grid", "pairs")
EXPLORATION_DEFAULTS = {"exploration": "transitions", "walk_length": None, "walk_step": None}
MAX_COMBINATIONS = 1000  # sub-studies in one file: each is a folder, a plan and a dry-run line
NOT_TRAINABLE = ("seed",)  # a run's seed is its world's
SETUP_KEY = "setup"  # the one [grid] key that is not a training field: a sub-study per setup


@dataclass(frozen=True)
class StudyFile:
    """A study file, resolved: every key checked, defaults filled where they are known."""

    name: str
    setup: str
    modes: list[str]
    worlds: int
    seed: int
    transitions: int | None
    train: dict[str, Any]
    grid: dict[str, list[Any]]
    run: dict[str, Any] = field(default_factory=dict)
    pairs: dict[str, list[Any]] = field(default_factory=dict)
    overrides: list[str] = field(default_factory=list)  # `section.key=value` given on the command line
    exploration: str = "transitions"  # or "walk" (lake/exploration.py)
    walk_length: int | None = None  # walks: steps per episode [WALK_LENGTH]
    walk_step: float | None = None  # walks: per step [the setup's default_walk_step]

    @property
    def world_seeds(self) -> list[int]:
        return list(range(self.seed, self.seed + self.worlds))

    def exploration_of(self, setup: str) -> Exploration:
        """How the datasets of `setup` explore: as `smgen generate` would with the same words."""
        from smspace.datagen.setups import get_setup

        if self.exploration != "walk":
            return Exploration()
        step = get_setup(setup).default_walk_step if self.walk_step is None else self.walk_step
        return Exploration("walk", WALK_LENGTH if self.walk_length is None else self.walk_length, step)

    def combinations(self) -> list[dict[str, Any]]:
        """One {field: value} per sub-study, in the file's order ([{}] without a grid): the grid's
        values crossed, each with every tuple of [pairs]; a combination given twice is one."""
        keys = list(self.grid)
        paired = [dict(zip(self.pairs, values, strict=True)) for values in zip(*self.pairs.values(), strict=True)]
        found, seen = [], set()
        for values in itertools.product(*self.grid.values()):
            for pair in paired or [{}]:
                combination = dict(zip(keys, values, strict=True)) | pair
                key = json.dumps(combination, sort_keys=True)
                if key not in seen:
                    seen.add(key)
                    found.append(combination)
        return found

    def setup_of(self, combination: dict[str, Any]) -> str:
        return combination.get(SETUP_KEY, self.setup)

    def config(self, combination: dict[str, Any]) -> TrainConfig:
        """The training template of one sub-study (its fields given, the others the defaults)."""
        trained = {k: v for k, v in combination.items() if k != SETUP_KEY}
        return TrainConfig(dataset="", **(self.train | trained))

    def given(self, combination: dict[str, Any]) -> frozenset[str]:
        """The fields the file sets, which a later run may not silently take from a recorded study."""
        return frozenset(self.train) | frozenset(k for k in combination if k != SETUP_KEY)

    def to_dict(self) -> dict[str, Any]:
        """As recorded: a study of transitions records no exploration (its record is the one it was
        before walks existed)."""
        raw = asdict(self)
        for key, default in EXPLORATION_DEFAULTS.items():
            if raw[key] == default:
                del raw[key]
        return raw


def folder_name(combination: dict[str, Any]) -> str:
    """The sub-folder of one combination: key=value pairs joined by commas ("" without a grid)."""
    return ",".join(f"{k}={_short(v)}" for k, v in combination.items())


def _short(value: Any) -> str:
    if isinstance(value, list):
        return "-".join(map(str, value))
    if isinstance(value, dict):
        return "-".join(f"{k}{_short(v)}" for k, v in sorted(value.items())) or "none"
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class StudyRequest:
    """What starts runs, whoever asks (a study file, a bench task, `smtrain sweep`'s flags, the
    Python API): a study, the bytes it was read from (recorded beside its runs as study-file.toml;
    None for flags, which have none) and where it came from, for messages."""

    study: StudyFile
    source: bytes | None
    where: str

    @classmethod
    def from_sections(
        cls, sections: dict[str, dict[str, Any]], where: str, default_name: str = "study"
    ) -> StudyRequest:
        """A study given as a file's sections ({"study": {…}, "train": {…}, "grid": {…}}), from code;
        its TOML is the source recorded beside its runs."""
        return cls.from_toml(toml_text(sections), where, default_name)

    @classmethod
    def from_flags(
        cls, setup: str, modes: list[str], worlds: int, seed: int, transitions: int | None,
        given: dict[str, Any], run: dict[str, Any], walk: dict[str, Any] | None = None,
    ) -> StudyRequest:  # fmt: skip
        """`smtrain sweep --setup …`: the flags as the study they describe (no grid; `given`: the
        training fields set on the command line, as a file's [train]; `walk`: the exploration
        flags, as a file's [study] keys, checked as they are)."""

        def bad(key: str, problem: str) -> SmspaceError:  # "study.walk_length" is --walk-length here
            return SmspaceError(f"--{key.removeprefix('study.').replace('_', '-')}: {problem}")

        explored = _exploration(walk or {}, bad)
        study = StudyFile("sweep", setup, modes, worlds, seed, transitions, given, {}, run, **explored)
        return cls(study, None, FLAGS)

    @classmethod
    def from_file(cls, path: Path | str, overrides: Sequence[str] = ()) -> StudyRequest:
        study, source = read_study(path, overrides)
        return cls(study, source, str(path))

    @classmethod
    def from_toml(cls, text: str, where: str, default_name: str = "study") -> StudyRequest:
        """A study written by code (a bench task's), parsed and checked as a file's would be."""
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise SmspaceError(f"{where} is not valid TOML: {e}") from None
        return cls(parse_study(raw, where, default_name=default_name), text.encode(), where)


def toml_text(sections: dict[str, dict[str, Any]]) -> str:
    """A study's sections as TOML (what a bench task or the Python API records as its source):
    plain values only, each read back by tomllib as it was given."""
    lines = []
    for name, table in sections.items():
        if not isinstance(table, dict):
            raise SmspaceError(f"{name}: must be a table of keys, got {type(table).__name__}")
        lines.append(f"[{_toml_key(name)}]")
        lines += [f"{_toml_key(key)} = {_toml_value(value, f'{name}.{key}')}" for key, value in table.items()]
    return "\n".join(lines) + "\n"


def _toml_key(key: Any) -> str:
    if not isinstance(key, str):
        raise SmspaceError(f"{key!r}: a key must be a string")
    if re.fullmatch(r"[A-Za-z0-9_-]+", key):
        return key  # a bare key, as a person writes it
    return json.dumps(key)  # a quoted key: JSON's string escapes are TOML's


def _toml_value(value: Any, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v, where)}" for k, v in value.items()) + "}"
    raise SmspaceError(f"{where}: {type(value).__name__} is not a value a study can hold")


def load_study(path: Path | str, overrides: Sequence[str] = ()) -> StudyFile:
    """The study in a TOML file, checked; SmspaceError naming the file and key otherwise."""
    return read_study(path, overrides)[0]


def read_study(path: Path | str, overrides: Sequence[str] = ()) -> tuple[StudyFile, bytes]:
    """The study and the bytes it was parsed from, read once (a pipe, `<(cat study.toml)`, reads
    empty the second time: the recorded copy was empty), with the command line's overrides."""
    path = Path(path)
    try:
        source = path.read_bytes()
        raw = tomllib.loads(source.decode())
    except FileNotFoundError:
        raise SmspaceError(f"no study file at {path}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SmspaceError(f"cannot read study file {path}: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise SmspaceError(f"{path} is not valid TOML: {e}") from None
    except RecursionError:  # thousands of nested arrays
        raise SmspaceError(f"{path} nests its values too deeply to be a study file") from None
    raw = apply_overrides(raw, overrides)
    study = parse_study(raw, str(path), default_name=path.stem)
    return replace(study, overrides=list(overrides)), source


OVERRIDE = re.compile(r"(?P<section>[a-z]+)\.(?P<key>[A-Za-z_][A-Za-z0-9_]*)=(?P<value>.*)", re.S)


def apply_overrides(raw: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """`section.key=value` on top of the parsed file; a key moves out of the other of [train],
    [grid] and [pairs] (train.n_h=5 replaces grid.n_h). Checked afterwards like the file itself."""
    raw = {section: dict(values) if isinstance(values, dict) else values for section, values in raw.items()}
    for text in overrides:
        match = OVERRIDE.fullmatch(text)
        if match is None or match["section"] not in SECTIONS:
            raise SmspaceError(
                f"override {text!r}: expected section.key=value with a section of {', '.join(SECTIONS)} "
                "(e.g. train.steps=2000 or grid.n_h=[3,5])"
            )
        section, key = match["section"], match["key"]
        try:
            value = tomllib.loads(f"v = {match['value']}")["v"]
        except tomllib.TOMLDecodeError:
            value = match["value"]  # a bare word: a string (train.model=shallow)
        if section in ("train", "grid", "pairs"):
            for other in ("train", "grid", "pairs"):
                if isinstance(raw.get(other), dict):
                    raw[other].pop(key, None)
        if section == "study" and key == "setup" and isinstance(raw.get("grid"), dict):
            raw["grid"].pop("setup", None)
        if section == "grid" and key == "setup" and isinstance(raw.get("study"), dict):
            raw["study"].pop("setup", None)
        target = raw.setdefault(section, {})
        if not isinstance(target, dict):
            raise SmspaceError(f"override {text!r}: [{section}] of the file is not a table")
        target[key] = value
    return raw


def parse_study(raw: dict[str, Any], where: str, default_name: str = "study") -> StudyFile:
    """`raw`: the parsed TOML; `where`: how errors name the file."""

    def bad(key: str, problem: str) -> SmspaceError:
        return SmspaceError(f"{where}: {key}: {problem}")

    for section in raw:
        if section not in SECTIONS:
            raise bad(section, f"unknown section (sections: {', '.join(SECTIONS)})")
        if not isinstance(raw[section], dict):
            raise bad(section, "must be a table ([" + section + "])")
    study = dict(raw.get("study", {}))
    varied = [section for section in ("grid", "pairs") if SETUP_KEY in raw.get(section, {})]
    if "setup" not in study and not varied:
        raise bad("study.setup", "missing (the setup every dataset of the study is generated with, or grid.setup)")
    if "setup" in study and varied:
        raise bad(f"{varied[0]}.setup", "is also set in [study]: give it in one place")
    known = {"name", "setup", "modes", "worlds", "seed", "transitions", *EXPLORATION_DEFAULTS}
    for key in study:
        if key not in known:
            raise bad(f"study.{key}", f"unknown key (keys: {', '.join(sorted(known))})")
    setup = ""
    if "setup" in study:
        setup = _string(study["setup"], bad, "study.setup")
        _check_setup(setup, bad, "study.setup")
    name = _string(study.get("name", default_name), bad, "study.name")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}", name):  # it names a folder: runs/<name>
        raise bad("study.name", f"{name!r} must be a plain folder name (letters, digits, '.', '_', '-'; no '/')")
    modes = _modes(study.get("modes", list(MODES)), bad)
    worlds = _bounded(WORLDS, study.get("worlds", 1), bad, "study.worlds")
    seed = _bounded(SEED, study.get("seed", 0), bad, "study.seed")
    if (problem := world_seeds_problem(seed, worlds)) is not None:  # world seeds seed .. seed + worlds - 1
        raise bad("study.seed", problem)
    transitions = study.get("transitions")
    if transitions is not None:
        transitions = _bounded(TRANSITIONS, transitions, bad, "study.transitions")

    explored = _exploration(study, bad)

    fields_by_name = {f.name: f for f in flag_fields() if f.name not in NOT_TRAINABLE}
    train = {k: _train_value(fields_by_name, k, v, bad, f"train.{k}") for k, v in raw.get("train", {}).items()}
    sizes = [len(v) if isinstance(v, list) else 1 for v in raw.get("grid", {}).values()]
    pair_sizes = {len(v) if isinstance(v, list) else 1 for v in raw.get("pairs", {}).values()}
    total = math.prod(sizes) * max(pair_sizes, default=1)
    if total > MAX_COMBINATIONS:  # before anything is built: 1000 x 1000 values took seconds
        shown = " x ".join(map(str, sizes + sorted(pair_sizes)[-1:]))
        raise bad("grid", f"{shown} = {total} combinations; at most {MAX_COMBINATIONS}")
    grid = {k: _varied(fields_by_name, train, "grid", k, values, bad) for k, values in raw.get("grid", {}).items()}
    pairs: dict[str, list[Any]] = {}
    for key, values in raw.get("pairs", {}).items():
        if key in grid:
            raise bad(f"pairs.{key}", "is also set in [grid]: give it in one place")
        pairs[key] = _varied(fields_by_name, train, "pairs", key, values, bad, once=False)
    if len({len(v) for v in pairs.values()}) > 1:
        shown = ", ".join(f"{k} {len(v)}" for k, v in pairs.items())
        raise bad("pairs", f"lists of different lengths ({shown}): each value is paired with those at its place")
    run = _run_section(raw.get("run", {}), bad)
    resolved = StudyFile(name, setup, modes, worlds, seed, transitions, train, grid, run, pairs, **explored)
    for combination in resolved.combinations():  # what only the whole config can check (lr > 0…)
        try:
            resolved.config(combination)
        except SmspaceError as e:
            at = folder_name(combination)
            raise SmspaceError(f"{where}: {f'[{at}] ' if at else ''}{e}") from None
    names = [folder_name(c) for c in resolved.combinations()]
    for name in names:  # each names a folder: no NUL, no separator, within a file system's 255 bytes
        if "\x00" in name or "/" in name or len(name.encode()) > 255:
            raise bad("grid", f"combination {name[:60]!r}… cannot name a folder (a NUL, a '/' or over 255 bytes)")
    if len(set(names)) != len(names):
        raise bad("grid", "two combinations would share a folder name; give values that print differently")
    return resolved


def _varied(fields_by_name: dict[str, Field], train: dict[str, Any], section: str, key: str, values: Any, bad,
            once: bool = True) -> list[Any]:  # fmt: skip
    """The values a [grid] or [pairs] key takes, each checked as the field's; a grid names each once."""
    if not isinstance(values, list) or not values:
        raise bad(f"{section}.{key}", "must be a non-empty list of values")
    if key in train:
        raise bad(f"{section}.{key}", "is also set in [train]: give it in one place")
    if key == SETUP_KEY:
        checked = [_string(v, bad, f"{section}.setup") for v in values]
        for setup_name in checked:
            _check_setup(setup_name, bad, f"{section}.setup")
    else:
        checked = [_train_value(fields_by_name, key, v, bad, f"{section}.{key}") for v in values]
    if once and len({json.dumps(v, sort_keys=True) for v in checked}) != len(checked):
        raise bad(f"{section}.{key}", "names a value twice")
    return checked


def _exploration(study: dict[str, Any], bad) -> dict[str, Any]:
    """[study]'s exploration keys, checked: a kind, and for walks a length and a step in bounds."""
    kind = study.get("exploration", "transitions")
    if kind not in KINDS:
        raise bad("study.exploration", f"{kind!r:.60} is not one of {', '.join(KINDS)}")
    found = {"exploration": kind, "walk_length": None, "walk_step": None}
    for key in ("walk_length", "walk_step"):
        if key in study and kind != "walk":
            raise bad(f"study.{key}", 'is for walks only (exploration "walk")')
    if "walk_length" in study:
        found["walk_length"] = _integer(study["walk_length"], bad, "study.walk_length", 1, MAX_LENGTH)
    if "walk_step" in study:
        step = study["walk_step"]
        if not (isinstance(step, int | float) and not isinstance(step, bool) and 0 < step <= MAX_STEP):
            raise bad("study.walk_step", f"{step!r:.60} is not a number in (0, {MAX_STEP}]")
        found["walk_step"] = float(step)
    return found


def _check_setup(setup: str, bad, key: str) -> None:
    from smspace.datagen.setups import setup_names

    if setup not in setup_names():
        raise bad(key, f"unknown setup {setup!r} (one of {', '.join(setup_names())})")


def _string(value: Any, bad, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise bad(key, f"expected a non-empty string, got {value!r}")
    return value


def _bounded(bounds: Bounded, value: Any, bad, key: str) -> int:
    if (problem := bounds.problem(value)) is not None:
        raise bad(key, problem)
    return value


def _integer(value: Any, bad, key: str, low: int | None, high: int | None) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        raise bad(key, f"expected an integer, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise bad(key, f"{value} is outside {low}..{high if high is not None else ''}")
    return value


def _modes(value: Any, bad) -> list[str]:
    if value == "all":
        return list(MODES)
    if not isinstance(value, list) or not value or not all(isinstance(m, str) for m in value):
        raise bad("study.modes", f'expected a list of modes such as ["MM", "MME"], or "all"; got {value!r}')
    for mode in value:
        if mode not in MODES:
            raise bad("study.modes", f"unknown mode {mode!r} (one of {', '.join(MODES)})")
    if len(set(value)) != len(value):
        raise bad("study.modes", "names a mode twice")
    return list(value)


def _default(f: Field) -> Any:
    return f.default_factory() if f.default is MISSING else f.default


def _train_value(fields_by_name: dict[str, Field], key: str, value: Any, bad, where: str) -> Any:
    """One training field's value, of the field's type and within its bounds."""
    f = fields_by_name.get(key)
    if f is None:
        if key in NOT_TRAINABLE:
            raise bad(where, "a run's seed is its world's: set study.seed")
        if key in PER_RUN:
            raise bad(where, "comes from each dataset, not from the study")
        raise bad(where, f"unknown training field (fields: {', '.join(sorted(fields_by_name))})")
    default = _default(f)
    if isinstance(default, list):
        if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise bad(where, f"expected a list of layer sizes such as [150, 100, 50], got {value!r}")
        return list(value)
    if isinstance(default, dict):
        if not isinstance(value, dict):
            raise bad(where, f"expected a table such as {{width = 64}}, got {value!r}")
        return dict(value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad(where, f"expected true or false, got {value!r}")
        return value
    if isinstance(default, float):
        if not finite_positive(value):
            raise bad(where, f"expected a finite positive number, got {value!r}")
        return float(value)
    if isinstance(default, int):
        return _integer(value, bad, where, f.metadata["min"], f.metadata["max"])
    if key == "compile":
        from smspace.train.config import COMPILE_CHOICES, compile_value

        compile_as = compile_value(value)
        if compile_as is None:
            raise bad(where, f"expected one of {', '.join(COMPILE_CHOICES)} (or true, false), got {value!r}")
        return compile_as
    if key == "model":
        from smspace.train.config import model_names

        if value not in model_names():
            raise bad(where, f"unknown model {value!r} (one of {', '.join(model_names())})")
    return _string(value, bad, where)


def _run_section(section: dict[str, Any], bad) -> dict[str, Any]:
    run = {}
    for key, value in section.items():
        if key not in RUN_KEYS:
            raise bad(f"run.{key}", f"unknown key (keys: {', '.join(RUN_KEYS)})")
        if key == "executor":
            if value not in EXECUTORS:
                raise bad("run.executor", f"expected one of {', '.join(EXECUTORS)}, got {value!r}")
            run[key] = value
        else:
            run[key] = _integer(value, bad, f"run.{key}", *RUN_KEYS[key])
    return run


def changes(recorded: dict[str, Any], now: dict[str, Any]) -> list[str]:
    """What differs between the study recorded in a folder and the file given now, one phrase per
    key ("study.worlds 3 -> 4"); how it runs ([run]) is not part of what a study computes."""
    out = []
    for section in ("name", "setup", "modes", "worlds", "seed", "transitions", *EXPLORATION_DEFAULTS, *TABLES):
        default = EXPLORATION_DEFAULTS.get(section)  # absent: a study recorded before walks, or of transitions
        a, b = recorded.get(section, default), now.get(section, default)
        if isinstance(a, dict) and isinstance(b, dict):
            out += described(a, b, prefix=f"{section}.")
        else:
            out += described({section: a}, {section: b})
    return out
