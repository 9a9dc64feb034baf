"""The Python API (docs/API.md): a lake, its datasets, generation and training, as a researcher's
notebook or script calls them. A thin layer over what the commands use: the same checks, the same
files, the same one-line errors (SmspaceError)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa

from smspace.common.errors import SmspaceError
from smspace.lake.bounds import world_seeds
from smspace.lake.catalog import read_catalog
from smspace.lake.dataset import Dataset, resolve_dataset
from smspace.lake.dataset import lake_store as _open_store
from smspace.lake.store import Store, open_store
from smspace.lake.transitions import parse_modes
from smspace.study.file import StudyRequest
from smspace.train.run_dir import RunView
from smspace.words import python_errors

if TYPE_CHECKING:
    from smspace.train.engine import Sink


class Lake:
    """A lake: a folder or an fsspec URL (s3://bucket/lake), and the datasets it holds."""

    def __init__(self, where: str | Path | Store | None = None):
        self.store = _open_store(where)  # None: $SMSPACE_LAKE, else data/lake

    @property
    def url(self) -> str:
        return self.store.url

    def catalog(self) -> pa.Table:
        """One row per complete dataset: id, setup, mode, world seed, transitions, shards, bytes…"""
        return read_catalog(self.store)

    def ids(self) -> list[str]:
        return self.catalog().column("id").to_pylist()

    def dataset(self, dataset_id: str) -> Dataset:
        return Dataset(resolve_dataset(dataset_id, self.store))

    def __repr__(self) -> str:
        return f"Lake({self.url!r})"


@python_errors
def open_lake(where: str | Path | Store | None = None) -> Lake:
    """A lake by folder or URL (None: $SMSPACE_LAKE, else data/lake)."""
    return Lake(where)


@python_errors
def load_dataset(ref: str | Path | Dataset, lake: Lake | str | Path | None = None) -> Dataset:
    """A dataset by id in a lake, or by its folder or URL: its manifest, and reads into numpy."""
    if isinstance(ref, Dataset):
        return ref
    store = lake.store if isinstance(lake, Lake) else lake
    return Dataset.open(str(ref), store)


@python_errors
def generate(
    setup: str,
    modes: str | list[str] = "all",
    worlds: int = 1,
    seed: int = 0,
    transitions: int | None = None,
    lake: Lake | str | Path | None = None,
    workers: int = 1,
    walk_length: int | None = None,
    walk_step: float | None = None,
) -> list[Dataset]:
    """Generate (or complete) the datasets of `worlds` worlds from `seed`, as `smgen generate`;
    with `walk_length`, walks of that many steps (`--exploration walk`)."""
    from smspace.datagen.generate import default_sizes
    from smspace.datagen.generate import generate as run
    from smspace.datagen.setups import get_setup
    from smspace.lake.exploration import Exploration

    spec = get_setup(setup)
    walk = Exploration()
    if walk_length is not None:
        walk = Exploration("walk", walk_length, spec.default_walk_step if walk_step is None else walk_step)
    store = lake.store if isinstance(lake, Lake) else _open_store(lake)  # generation checks it
    mode_list = parse_modes(modes) if isinstance(modes, str) else list(modes)
    n, shard = default_sizes(setup, walk, transitions, None)
    seeds = world_seeds(seed, worlds)
    results = run(store, setup, mode_list, seeds, n, shard, workers=workers, exploration=walk)
    return [Dataset(store.child(manifest.dataset_id)) for manifest, _ in results]


class Run(RunView):
    """A run folder: config, metrics, embeddings of h at every evaluation, checkpoint, status."""

    def __repr__(self) -> str:
        return f"Run({self.url!r})"


@python_errors
def fit(
    dataset: str | Path | Dataset,
    out: str | Path | None = None,
    lake: Lake | str | Path | None = None,
    overwrite: bool = False,
    sinks: Sequence[Sink] = (),
    **flags: Any,
) -> Run:
    """Train one run on a dataset, as `smtrain fit`: `flags` are TrainConfig's fields (steps,
    n_h, encoder_layers, model, model_params, seed…), checked as the command checks its flags.
    `sinks`: objects with `on_evaluation(evaluation)` and `on_finish(step, message)` that see each
    evaluation after the run folder committed it (docs/API.md, "Your own logger")."""
    from smspace.train.config import TrainConfig, flag_fields
    from smspace.train.fit import fit as run_fit
    from smspace.train.fit import plan_fit

    names = {f.name for f in flag_fields()}
    unknown = sorted(set(flags) - names)
    if unknown:
        raise TypeError(f"fit() got unknown training fields {unknown}; choose from {sorted(names)}")
    template = TrainConfig(dataset="", **flags)
    ds = load_dataset(dataset, lake)
    plan = plan_fit(template, ds.url, None, None if out is None else str(out), None, overwrite, frozenset(flags), 1)
    run = plan.start()
    run_fit(plan.cfg, run, sinks=sinks)
    return Run(run.store)


@python_errors
def resume(run: str | Path | RunView, steps: int | None = None, sinks: Sequence[Sink] = ()) -> Run:
    """Continue a run from its last checkpoint (`steps` may extend it: train/terms.py)."""
    from smspace.train.config import TrainConfig
    from smspace.train.fit import fit as run_fit
    from smspace.train.fit import plan_fit

    where = run.url if isinstance(run, RunView) else str(run)
    template = TrainConfig(dataset="", **({} if steps is None else {"steps": steps}))
    plan = plan_fit(template, None, None, None, where, False, frozenset({"steps"} if steps is not None else ()), 1)
    started = plan.start()
    run_fit(plan.cfg, started, resume=True, sinks=sinks)
    return Run(started.store)


@python_errors
def open_run(where: str | Path | RunView) -> Run:
    """An existing run folder (a folder or an fsspec URL), to read its config, metrics and h."""
    return Run.open(where.store if isinstance(where, RunView) else where)


@python_errors
def find_runs(where: str | Path | Store) -> list[Run]:
    """Every run folder at or below `where` (a folder or an fsspec URL): a lone run, a sweep, a
    study with its grid, a bench's results; found by the scanner `smtrain ls`, `report` and
    `leaderboard` use (lake/scan.py), in path order."""
    from smspace.lake.scan import descend, folders_holding
    from smspace.train.run_dir import CONFIG

    store = where if isinstance(where, Store) else open_store(where)
    if store.is_file():
        raise SmspaceError(f"{store.url} is a file, not a folder of runs")
    return [Run.open(descend(store, name)) for name in folders_holding(store, CONFIG)]


@python_errors
def define_study(
    study: dict[str, Any],
    train: dict[str, Any] | None = None,
    grid: dict[str, list[Any]] | None = None,
    pairs: dict[str, list[Any]] | None = None,
    run: dict[str, Any] | None = None,
) -> StudyRequest:
    """A study from code, section by section as a study file has them (docs/STUDIES.md), checked
    as a file is: `smspace.define_study({"setup": "grid", "worlds": 2}, train={"steps": 200})`. Its TOML
    is recorded beside its runs as a file's would be."""
    sections = {"study": study, "train": train, "grid": grid, "pairs": pairs, "run": run}
    given = {name: table for name, table in sections.items() if table is not None}
    return StudyRequest.from_sections(given, "smspace.define_study()")


@python_errors
def run_study(
    study_file: str | Path | StudyRequest,
    out: str | Path | None = None,
    lake: Lake | str | Path | None = None,
    workers: int | None = None,
    overrides: Sequence[str] = (),
    overwrite: bool = False,
) -> list[Run]:
    """Run (or resume, or extend) a study file (docs/STUDIES.md), as `smtrain sweep STUDY.toml`, or
    a study built by `smspace.define_study`;
    `overrides` as the command's (["train.steps=2000", "grid.n_h=[3,5]"]); `overwrite` replaces
    runs made with other terms. Workers are spawned processes that import your script again: call
    it under `if __name__ == "__main__":` (docs/API.md)."""
    from smspace.study.runner import run_study as run

    store = lake.store if isinstance(lake, Lake) else open_lake(lake).store
    where = None if out is None else str(out)
    runs = run(study_file, store, where, overwrite=overwrite, workers=workers, overrides=overrides)
    return [Run(r.store) for r in runs]


@python_errors
def dry_run(
    study_file: str | Path | StudyRequest,
    out: str | Path | None = None,
    lake: Lake | str | Path | None = None,
    workers: int | None = None,
    overrides: Sequence[str] = (),
    overwrite: bool = False,
) -> list[str]:
    """What a study (a file, or `smspace.define_study`'s) would generate, train, store and take, as
    `smtrain sweep STUDY.toml --dry-run` prints it, one line each; writes nothing."""
    from smspace.study.runner import dry_run as plan

    store = lake.store if isinstance(lake, Lake) else open_lake(lake).store
    return plan(study_file, store, None if out is None else str(out), workers, overwrite, overrides)


@python_errors
def report(runs: Sequence[str | Path | RunView], out: str | Path) -> Path:
    """The figures, tables and report.md of runs (run folders or study folders), as `smtrain
    report`; returns report.md, which opens with the notes the command prints (runs left out,
    studies kept apart)."""
    from smspace.train.report import report as draw

    written, _ = draw([r.url if isinstance(r, RunView) else r for r in runs], Path(out))
    return next(p for p in written if p.name == "report.md")
