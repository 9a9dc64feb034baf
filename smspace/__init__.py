"""smspace: sensorimotor datasets in an MCAP data lake, the sensorimotor predictive network, and
the measures of how much of the structure of space it learned.

The public API is what `__all__` names (docs/API.md shows each in use); everything else may
change. Names load on first use, so `import smspace` stays light. (`smspace.fit` trains a run, as
`smtrain fit`; `smspace.train` is the package of the training code.)

    import smspace
    lake = smspace.open_lake("data/samples")           # a folder, or s3://bucket/lake
    ds = smspace.load_dataset("grid-seed0-MME", lake)   # an id in the lake, a folder or a URL
    tr = ds.transitions(limit=1000)                    # numpy columns: m_t, s_t, m_t1, s_t1, p_t, …
    run = smspace.fit(ds, out="runs/api", steps=200, eval_every=100)
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

__all__ = [
    "MODES",
    "Batch",
    "Dataset",
    "Lake",
    "Run",
    "SmspaceError",
    "SpatialScores",
    "TrainConfig",
    "TransitionStream",
    "Transitions",
    "affine_projection",
    "define_study",
    "dry_run",
    "find_runs",
    "fit",
    "generate",
    "load_dataset",
    "open_lake",
    "open_run",
    "report",
    "resume",
    "run_study",
    "spatial_scores",
    "worker_batches",
]

_WHERE = {
    "MODES": "smspace.lake.transitions",
    "Transitions": "smspace.lake.transitions",
    "SmspaceError": "smspace.common.errors",
    "SpatialScores": "smspace.metrics.spatial",
    "spatial_scores": "smspace.metrics",
    "affine_projection": "smspace.metrics",
    "TrainConfig": "smspace.train.config",
    "TransitionStream": "smspace.train.loader",
    "Batch": "smspace.train.loader",
    "worker_batches": "smspace.train.worker_batches",
    "Dataset": "smspace.lake.dataset",
    "Run": "smspace.api",
    "Lake": "smspace.api",
    "generate": "smspace.api",
    "load_dataset": "smspace.api",
    "open_lake": "smspace.api",
    "resume": "smspace.api",
    "open_run": "smspace.api",
    "run_study": "smspace.api",
    "dry_run": "smspace.api",
    "define_study": "smspace.api",
    "find_runs": "smspace.api",
    "report": "smspace.api",
    "fit": "smspace.api",
}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'smspace' has no attribute {name!r}")
    value = getattr(import_module(_WHERE[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])


if TYPE_CHECKING:
    from smspace.api import (
        Lake,
        Run,
        define_study,
        dry_run,
        find_runs,
        fit,
        generate,
        load_dataset,
        open_lake,
        report,
        resume,
    )
    from smspace.common.errors import SmspaceError
    from smspace.lake.dataset import Dataset
    from smspace.lake.transitions import MODES, Transitions
    from smspace.metrics import affine_projection, spatial_scores
    from smspace.metrics.spatial import SpatialScores
    from smspace.train.config import TrainConfig
    from smspace.train.loader import Batch, TransitionStream
    from smspace.train.worker_batches import worker_batches
