"""The training configuration: the single source of every training flag, its default and its help.

Defaults are the paper's (docs/MODEL.md §3). `smtrain fit` and `smtrain sweep` build their flags
from the fields marked `flag(...)`, and every run stores its resolved config in config.json.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from lake.manifest import SEED_MAX  # a run's seed is its world's in a sweep

PAPER_PREDICTOR = (200, 150, 100)


def flag(
    default: Any, help: str, name: str | None = None, minimum: float | None = None, maximum: float | None = None
) -> Any:
    """A config field that is also a command-line flag (`--field-name` unless `name` is given)."""
    kwargs: dict[str, Any] = {"metadata": {"help": help, "flag": name, "min": minimum, "max": maximum}}
    if isinstance(default, list):
        kwargs["default_factory"] = lambda: list(default)
    else:
        kwargs["default"] = default
    return field(**kwargs)


@dataclass
class TrainConfig:
    # what the run trains on, filled from the dataset's manifest (`for_dataset`)
    dataset: str  # the dataset folder, resolved
    dataset_id: str = ""
    dataset_config_hash: str = ""
    dataset_shards_sha256: str = ""  # sha256 over the shards' recorded sha256s: a regenerated dataset differs
    setup: str = ""
    mode: str = ""
    # the flags
    steps: int = flag(100_000, "Training steps.", minimum=1)
    batch_size: int = flag(100, "Transitions per step.", minimum=1)
    n_h: int = flag(3, "Dimension of h.", name="--nh", minimum=1)
    encoder_layers: list[int] = flag([], "Net_enc hidden sizes, e.g. 150,100,50 [default: the paper's for the setup].")  # noqa: RUF009 - flag() returns a field
    predictor_layers: list[int] = flag(list(PAPER_PREDICTOR), "Net_pred hidden sizes.")  # noqa: RUF009
    lr_start: float = flag(1e-3, "Learning rate at step 0.")
    lr_end: float = flag(1e-5, "Learning rate after the decay.")
    lr_decay_steps: int = flag(0, "Steps of the linear decay [0: 80% of --steps].", minimum=0)
    eval_every: int = flag(1000, "Steps between evaluations.", minimum=1)
    seed: int = flag(0, "Seed of the initial weights and of the data order.", minimum=0, maximum=SEED_MAX)
    device: str = flag("cpu", "cpu or cuda.")
    threads: int = flag(1, "torch CPU threads.", minimum=1)
    loader_workers: int = flag(0, "DataLoader worker processes per run.", minimum=0)
    # fixed by design, recorded so that a run folder says everything its numbers depend on
    eval_transitions: int = 4096  # the fixed set the evaluation loss is computed on
    shuffle_window: int = 8

    def __post_init__(self) -> None:
        if self.lr_decay_steps <= 0:
            self.lr_decay_steps = max(1, round(0.8 * self.steps))

    @property
    def run_name(self) -> str:
        """The default run folder name under `--out`."""
        return f"{self.dataset_id}-nh{self.n_h}-seed{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in raw.items() if k in known})

    def for_dataset(self, folder: Path, manifest) -> TrainConfig:
        """This config bound to a dataset: its identity, setup, mode and the setup's default encoder."""
        encoder = self.encoder_layers or default_encoder_layers(manifest.setup)
        return replace(
            self,
            dataset=str(Path(folder).resolve()),
            dataset_id=manifest.dataset_id,
            dataset_config_hash=manifest.config_hash,
            dataset_shards_sha256=manifest.shards_digest,
            setup=manifest.setup,
            mode=manifest.mode,
            encoder_layers=list(encoder),
        )


def default_encoder_layers(setup: str) -> tuple[int, ...]:
    from datagen.setups import get_setup  # the setup owns its body and so the paper's encoder for it

    return get_setup(setup).encoder_layers


def flag_fields() -> list:
    """The fields that are command-line flags, in declaration order."""
    return [f for f in fields(TrainConfig) if "help" in f.metadata]


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear from lr_start to lr_end over lr_decay_steps, then constant (docs/MODEL.md §3)."""
    frac = min(step, cfg.lr_decay_steps) / cfg.lr_decay_steps
    return cfg.lr_start + (cfg.lr_end - cfg.lr_start) * frac
