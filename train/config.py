"""The training configuration: the single source of every training flag, its default and its help.

Defaults are the paper's (docs/MODEL.md §3). `smtrain fit` and `smtrain sweep` build their flags
from the fields marked `flag(...)`, and every run stores its resolved config in config.json.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.lake.manifest import SEED_MAX  # a run's seed is its world's in a sweep
from smspace.lake.store import Store, canonical, open_store

# torch, the networks and the precision probe are imported where they are used: the command line
# builds its flags from this module, and `smtrain --help` or a Tab must not wait for torch
RUNS = "runs"  # where runs go without --out: runs/<dataset>-nh<N>-seed<S>, a study's runs/<name>
DEFAULT_MODEL = "sensorimotor"
ENTRY_POINTS = "smspace.models"  # where packages register networks of their own (docs/API.md)
PRECISIONS = ("fp32", "bf16", "auto")
COMPILE_CHOICES = ("off", "on", "auto")  # --compile alone: on


def finite_positive(value: object) -> bool:
    """A number (not a boolean), finite and above 0: what a learning rate must be, however given."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and value > 0


def compile_value(value: object) -> str | None:
    """A --compile value as config.json, a study file or a flag gives it; true and false were its
    values before auto. None: not one."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return value if value in COMPILE_CHOICES else None


PAPER_PREDICTOR = (200, 150, 100)
MAX_WIDTH = 65536  # a layer (or h) wider than this is a typo, not an experiment
MAX_LAYERS = 32
LAYER_BOUNDS = f"at most {MAX_LAYERS} layers of 1..{MAX_WIDTH} units"


def layers_within_bounds(sizes: Sequence[int]) -> bool:
    """The one rule for layer lists, whether they come from a flag, a study file or Python."""
    return len(sizes) <= MAX_LAYERS and all(1 <= s <= MAX_WIDTH for s in sizes)


MAX_WINDOW = 4096  # steps per window: longer than any walk a lake holds is a typo
UNIT_BYTES = 256  # the loader's record of one batch unit (a small Python object and its list slot)


def flag(
    default: Any, help: str, name: str | None = None, minimum: float | None = None, maximum: float | None = None
) -> Any:
    """A config field that is also a command-line flag (`--field-name` unless `name` is given)."""
    kwargs: dict[str, Any] = {"metadata": {"help": help, "flag": name, "min": minimum, "max": maximum}}
    if isinstance(default, list):
        kwargs["default_factory"] = lambda: list(default)
    elif isinstance(default, dict):
        kwargs["default_factory"] = lambda: dict(default)
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
    dataset_transitions: int = 0  # its size: runs on datasets of other sizes are not one study
    setup: str = ""
    mode: str = ""
    # how its agent explored (lake/exploration.py, the manifest's record): None for independent
    # transitions; walks and transitions of one world are not one study
    exploration: dict[str, Any] | None = None
    # the flags
    steps: int = flag(100_000, "Training steps.", minimum=1, maximum=10**10)
    batch_size: int = flag(100, "Transitions per step.", minimum=1, maximum=10**7)
    window: int = flag(
        1,
        "Consecutive steps per sample, for a model that reads windows (walk datasets only; docs/MODEL.md §6): "
        "each of a batch's rows is K steps of one episode.",
        minimum=1,
        maximum=MAX_WINDOW,
    )
    n_h: int = flag(3, "Dimension of h.", name="--nh", minimum=1, maximum=MAX_WIDTH)
    encoder_layers: list[int] = flag([], "Net_enc hidden sizes, e.g. 150,100,50 [default: the paper's for the setup].")  # noqa: RUF009 - flag() returns a field
    predictor_layers: list[int] = flag(list(PAPER_PREDICTOR), "Net_pred hidden sizes.")  # noqa: RUF009
    model: str = flag(DEFAULT_MODEL, "The network: sensorimotor (docs/MODEL.md §3) or one a plugin registers.")
    model_params: dict[str, Any] = flag({}, "The model's own parameters, as a JSON object.")  # noqa: RUF009
    lr_start: float = flag(1e-3, "Learning rate at step 0.")
    lr_end: float = flag(1e-5, "Learning rate after the decay.")
    lr_decay_steps: int = flag(0, "Steps of the linear decay [0: 80% of --steps].", minimum=0)
    eval_every: int = flag(1000, "Steps between evaluations.", minimum=1, maximum=10**10)
    seed: int = flag(0, "Seed of the initial weights and of the data order.", minimum=0, maximum=SEED_MAX)
    device: str = flag("cpu", "cpu or cuda.")
    threads: int = flag(1, "torch CPU threads.", minimum=1, maximum=256)
    loader_workers: int = flag(0, "DataLoader worker processes per run.", minimum=0, maximum=64)
    precision: str = flag(
        "fp32",
        "fp32, bf16 (the training step's matmuls in bfloat16; weights, Adam, loss and evaluation in fp32) "
        "or auto (decided when the run is created: docs/MODEL.md §3).",
    )
    compile: str = flag(
        "off",
        "The training step through torch.compile: off, on (a CPU needs a C++ compiler; --compile alone) or "
        "auto (on where the session's run-steps repay compilation; decided and recorded per session).",
    )
    precision_asked: str = ""  # what --precision said (auto); `precision` is what it was resolved to
    # the model's package when a plugin ({} for smspace's own): distribution, version, code hash
    model_plugin: dict[str, str] = field(default_factory=dict)
    # fixed by design, recorded so that a run folder says everything its numbers depend on
    eval_transitions: int = 4096  # the fixed set the evaluation loss is computed on
    shuffle_window: int = 8
    world_size: int = 1  # processes training this one run (torchrun); a resume needs the same
    # how the run was extended (train/terms.py, rule 3): [{"from_steps": …, "to_steps": …}, …]
    extensions: list[dict[str, int]] = field(default_factory=list)
    run_id: str = ""  # given when the run folder is created; every file of the run carries it
    # what each training session ran on (common/provenance.py): smspace, git commit, torch, CPU, device
    sessions: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        for f in fields(self):  # the bounds each field declares hold for flags, study files and the API alike
            low, high = f.metadata.get("min"), f.metadata.get("max")
            value = getattr(self, f.name)
            if (low is not None or high is not None) and not _within(value, low, high):
                raise SmspaceError(
                    f"{flag_name(f)} must be an integer in {low}..{'' if high is None else high}, got {value!r}"
                )
        for name in ("lr_start", "lr_end"):
            value = getattr(self, name)
            if not finite_positive(value):
                raise SmspaceError(f"--{name.replace('_', '-')} must be a finite positive number, got {value}")
        for name in ("encoder_layers", "predictor_layers"):
            sizes = getattr(self, name)
            if not layers_within_bounds(sizes):
                raise SmspaceError(f"--{name.replace('_', '-')}: {LAYER_BOUNDS}")
        if self.lr_decay_steps <= 0:
            self.lr_decay_steps = max(1, round(0.8 * self.steps))
        compile_as = compile_value(self.compile)
        if compile_as is None:
            raise SmspaceError(f"--compile {self.compile!r}: one of {', '.join(COMPILE_CHOICES)}")
        self.compile = compile_as
        if self.precision not in PRECISIONS:
            raise SmspaceError(f"--precision {self.precision!r}: one of {', '.join(PRECISIONS)}")
        self.precision_asked = self.precision_asked or self.precision
        if self.precision == "auto":  # decided once, here; the run records what was asked and decided
            from smspace.train.precision import resolve

            self.precision = resolve(self.precision, self.device)[0]

    @property
    def run_name(self) -> str:
        """The default run folder name under `--out`."""
        return f"{self.dataset_id}-nh{self.n_h}-seed{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        """config.json's fields. `window` only when a run reads windows, `exploration` only for a
        walk: a run of single transitions keeps the bytes (and the terms) it had before either existed."""
        raw = asdict(self)
        if raw["window"] == 1:
            del raw["window"]
        if raw["exploration"] is None:
            del raw["exploration"]
        return raw

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in raw.items() if k in known})

    def for_setup(
        self, setup: str, transitions: int, encoder_layers: Sequence[int], exploration: dict[str, Any] | None = None
    ) -> TrainConfig:
        """This config for datasets of one setup, size and exploration: what a study's runs share;
        the encoder the setup suggests unless one was given."""
        from smspace.train.model import plugin_record

        encoder = self.encoder_layers or encoder_layers
        return replace(
            self,
            setup=setup,
            dataset_transitions=transitions,
            exploration=exploration,
            encoder_layers=list(encoder),
            model_plugin=plugin_record(self.model),
        )

    def for_dataset(self, folder: Store | Path, manifest) -> TrainConfig:
        """This config bound to a dataset: its identity, setup, mode and the encoder its manifest
        records for the setup's agent."""
        explored = manifest.config.get("exploration")
        return replace(
            self.for_setup(manifest.setup, manifest.transitions, default_encoder_layers(manifest), explored),
            dataset=canonical(open_store(folder)),
            dataset_id=manifest.dataset_id,
            dataset_config_hash=manifest.config_hash,
            dataset_shards_sha256=manifest.shards_digest,
            mode=manifest.mode,
        )


# by motors, for manifests that do not record their network
PAPER_ENCODERS = {3: (150, 100, 50), 6: (500, 400, 300, 200)}


def default_encoder_layers(manifest) -> tuple[int, ...]:
    """The encoder the dataset's manifest records for its agent (the setup's choice); manifests
    written before they recorded it get the paper's rule for their number of motors."""
    if manifest.network and manifest.network.get("encoder_layers"):
        return tuple(manifest.network["encoder_layers"])
    return PAPER_ENCODERS.get(manifest.n_motor, PAPER_ENCODERS[3])


def _builtin_model(name: str) -> Any:
    from smspace.train.model import SensorimotorNet  # torch, only once a run needs its network

    return SensorimotorNet


MODELS = plugins.Registry("model", ENTRY_POINTS, (DEFAULT_MODEL,), _builtin_model)


def model_names() -> tuple[str, ...]:
    """Every model a run may name: the built-in one and the registered ones (not loaded)."""
    return MODELS.names()


def flag_name(f) -> str:
    """The command-line flag of a config field: `--field-name` unless the field names another."""
    return f.metadata["flag"] or "--" + f.name.replace("_", "-")


def _within(value: Any, low: int | None, high: int | None) -> bool:
    if not isinstance(value, int) or isinstance(value, bool):
        return False
    return (low is None or value >= low) and (high is None or value <= high)


def flag_fields() -> list:
    """The fields that are command-line flags, in declaration order."""
    return [f for f in fields(TrainConfig) if "help" in f.metadata]


def parameter_count(cfg: TrainConfig, n_motor: int, n_sensor: int) -> int:
    """The run's model built on the meta device: its parameters counted, nothing allocated."""
    import torch

    from smspace.train.model import build_model
    from smspace.train.model import parameter_count as count_parameters

    with torch.device("meta"):
        model = build_model(
            cfg.model, n_motor, n_sensor, cfg.n_h, cfg.encoder_layers, cfg.predictor_layers, cfg.model_params
        )
    return count_parameters(model)


def memory_needed(cfg: TrainConfig, n_motor: int, n_sensor: int, n_regular: int, runs: int = 1) -> int:
    """Bytes `runs` runs of this config need, estimated before anything is allocated: weights,
    gradients and Adam's two moments; activations kept for the backward pass; the evaluation set;
    the loader's shuffle window."""
    params = parameter_count(cfg, n_motor, n_sensor)
    widths = 2 * (sum(cfg.encoder_layers) + cfg.n_h) + sum(cfg.predictor_layers) + 2 * cfg.n_h + 2 * n_sensor
    row = 4 * (2 * n_motor + 2 * n_sensor)
    per_run = (
        16 * params
        + 4 * 3 * cfg.batch_size * widths
        + 4 * max(cfg.batch_size, n_regular) * (sum(cfg.encoder_layers) + cfg.n_h)
        + cfg.eval_transitions * (row + 4 * widths)
        + row * cfg.window * (cfg.shuffle_window * 1024 + 2 * cfg.batch_size)
    )
    return runs * per_run


def available_memory() -> int:
    """MemAvailable of this machine (Linux), or a generous guess elsewhere."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 1 << 40


def check_resources(cfg: TrainConfig, manifest, runs: int = 1) -> None:
    """Refuse, before allocating, what this machine cannot hold or what the dataset cannot feed."""
    n_sensor = math.prod(manifest.sensor_shape)
    if cfg.batch_size > manifest.transitions:
        raise SmspaceError(
            f"--batch-size {cfg.batch_size} is larger than the dataset ({manifest.transitions} transitions)"
        )
    units = unit_count(manifest)
    consumers = cfg.world_size * max(1, cfg.loader_workers)
    if units < consumers:  # the loader gives each consumer whole batch units of ~1024 transitions
        raise SmspaceError(
            f"dataset {manifest.dataset_id} has {units} batch unit(s) of {manifest.config['batch_size']} transitions, "
            f"fewer than the {consumers} readers of {cfg.world_size} process(es) x {max(1, cfg.loader_workers)} "
            "loader worker(s); use fewer --loader-workers"
        )
    needed = memory_needed(cfg, manifest.n_motor, n_sensor, manifest.regular_sampling["count"], runs)
    needed += units * UNIT_BYTES * consumers  # every reader holds the table of units
    free = available_memory()
    if needed > free:
        raise SmspaceError(
            f"{runs} run(s) of this config need about {needed / 2**30:.1f} GiB of memory; "
            f"{free / 2**30:.1f} GiB are available"
        )


def unit_count(manifest) -> int:
    """The loader's units of work (one batch message each) in a dataset."""
    from smspace.lake.exploration import stored_batch

    batch = stored_batch(manifest.config)
    return sum(-(-shard["transitions"] // batch) for shard in manifest.shards)
