"""The resolved training configuration (SPEC 3 defaults = the paper's), stored in every run."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class TrainConfig:
    dataset: str  # the dataset folder, resolved
    dataset_id: str = ""
    dataset_config_hash: str = ""
    steps: int = 100_000
    batch_size: int = 100
    n_h: int = 3
    encoder_layers: list[int] = field(default_factory=list)  # empty: the paper's for the motor count
    predictor_layers: list[int] = field(default_factory=lambda: [200, 150, 100])
    lr_start: float = 1e-3
    lr_end: float = 1e-5
    lr_decay_steps: int = 0  # 0: 80 % of steps (80000 of the paper's 100000)
    eval_every: int = 1000
    eval_transitions: int = 4096  # the fixed set the evaluation loss is computed on
    seed: int = 0
    device: str = "cpu"
    threads: int = 1
    loader_workers: int = 0
    shuffle_window: int = 8

    def __post_init__(self) -> None:
        if self.lr_decay_steps <= 0:
            self.lr_decay_steps = max(1, round(0.8 * self.steps))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> TrainConfig:
        return cls(**{k: v for k, v in raw.items() if k in cls.__dataclass_fields__})


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear from lr_start to lr_end over lr_decay_steps, then constant (SPEC 3)."""
    frac = min(step, cfg.lr_decay_steps) / cfg.lr_decay_steps
    return cfg.lr_start + (cfg.lr_end - cfg.lr_start) * frac
