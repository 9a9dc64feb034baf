"""A run's terms: what its numbers depend on, and what may change when it is resumed, when its
study is extended, or when runs are averaged. The one place these rules live (README, "Resuming
and extending"); `smtrain fit --resume`, `smtrain sweep` and `smtrain report` apply them.

1. Every field of a run's config is fixed when the run is created, but `steps`.
2. `steps` may grow (the run is extended), never shrink: a shorter run is another run, since its
   learning rate would stop mid-decay. `--resume` takes no other flag, and runs on as many
   processes as the run was trained on (each rank reads its own share of the data).
3. An extended run keeps the learning-rate schedule it recorded (`lr_decay_steps`): the command
   says so in one line, and config.json lists the extension under `extensions`. A fresh run of
   the same length decays over 80 % of it instead, so the two are different studies (rule 5).
4. A sweep's output folder records its study's terms in `study.json` the first time. A re-run must
   have the same terms but `steps`, which may grow for every run of the study, new worlds and
   modes included; the study's recorded schedule then holds for all of them.
5. Runs are averaged together only when they share every term but those that vary within a study
   (`PER_RUN`: dataset, mode, seed) and how they were run (`EXECUTION`); runs are trained as one
   ensemble only when they share the same terms and the device and compilation of its one loop.

Everything is checked before anything is written; what breaks a rule is refused in one line.
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Any

from smspace.common.differing import differing
from smspace.common.errors import SmspaceError
from smspace.common.plugins import changes
from smspace.train.config import TrainConfig
from smspace.train.model import plugin_record

PER_RUN = ("dataset", "dataset_id", "dataset_config_hash", "dataset_shards_sha256", "mode", "seed", "run_id")
EXECUTION = ("device", "threads", "loader_workers", "world_size", "compile")  # how a run ran, not what it computed
HISTORY = ("extensions", "sessions", "precision_asked")  # what happened to a run or was asked, not what it computes


def terms(cfg: TrainConfig) -> dict[str, Any]:
    """The fields that runs of one study share (rule 5)."""
    return {k: v for k, v in cfg.to_dict().items() if k not in (*PER_RUN, *EXECUTION, *HISTORY)}


RUN_BY_ONE_LOOP = ("device", "compile")  # how runs ran, but an ensemble's one loop runs all its members so


def ensemble_terms(cfg: TrainConfig) -> dict[str, Any]:
    """What runs trained as one ensemble must share: their study's terms (rule 5), so that a new
    config field is checked here the moment it becomes a term, and what the shared loop applies."""
    return terms(cfg) | {k: getattr(cfg, k) for k in RUN_BY_ONE_LOOP}


def check_one_ensemble(cfgs: list[TrainConfig]) -> None:
    first = ensemble_terms(cfgs[0])
    for cfg in cfgs[1:]:
        diff = differing(first, ensemble_terms(cfg))
        if diff:
            raise SmspaceError(f"runs of one ensemble must share {', '.join(diff)}")


def grown(recorded_steps: int, steps: int, shortened: str) -> dict[str, int] | None:
    """Rule 2, for a run and a study alike: the extension from the recorded length to `steps` (None:
    the same length); `shortened`, the refusal in the caller's words, when `steps` is fewer."""
    if steps < recorded_steps:
        raise SmspaceError(shortened)
    return None if steps == recorded_steps else {"from_steps": recorded_steps, "to_steps": steps}


def schedule(cfg: TrainConfig) -> str:
    return f"learning rate {cfg.lr_start:g} to {cfg.lr_end:g} over {cfg.lr_decay_steps} steps, then constant"


def resumed(recorded: TrainConfig, where: str, steps: int | None, world_size: int) -> tuple[TrainConfig, str | None]:
    """The config `--resume` continues with (rules 1-3), and the line that says what changed."""
    same_model_code(recorded, where)
    if recorded.world_size != world_size:
        raise SmspaceError(
            f"{where} was trained on {recorded.world_size} process(es); resume it on as many "
            f"(--nproc {recorded.world_size}, or torchrun --nproc-per-node {recorded.world_size}), not {world_size}"
        )
    if steps is None:
        return recorded, None
    extension = grown(
        recorded.steps, steps,
        f"--steps {steps} is fewer than the {recorded.steps} steps of {where}: a run is never shortened "
        f"(its {schedule(recorded)}); train a new run with --steps {steps}",
    )  # fmt: skip
    if extension is None:
        return recorded, None
    extended = replace(recorded, steps=steps, extensions=[*recorded.extensions, extension])
    return (
        extended,
        f"extending {where} from {recorded.steps} to {steps} steps on its recorded schedule ({schedule(recorded)})",
    )


def same_model_code(recorded: TrainConfig, where: str) -> None:
    """A run is trained by the code it was created with (rule 1): a plugin model whose installed
    version or code differs from the recorded one is another model."""
    if not recorded.model_plugin:  # smspace's own model, or a run recorded before plugins were
        return
    now = plugin_record(recorded.model)
    if now != recorded.model_plugin:
        raise SmspaceError(
            f"model {recorded.model!r} changed since {where} was created "
            f"({changes(recorded.model_plugin, now)}); a run is trained by one "
            "model's code: install the recorded one, or train a new run"
        )


def study_template(
    recorded: dict[str, Any] | None, requested: TrainConfig, explicit: set[str], where: str
) -> tuple[TrainConfig, str | None]:
    """The template a sweep trains with (rule 4), and the line that says what changed. `recorded`:
    the terms of the study already in the folder (None: a new study); `explicit`: the fields the
    user gave (a schedule derived from --steps is not a request to change the recorded one)."""
    if recorded is None:
        return requested, None
    asked = terms(requested)
    steps = asked["steps"]
    extension = grown(
        recorded["steps"], steps,
        f"--steps {steps} is fewer than the {recorded['steps']} steps of the study in {where}: "
        "a study is never shortened; use another --out",
    )  # fmt: skip
    if "lr_decay_steps" not in explicit:
        asked["lr_decay_steps"] = recorded["lr_decay_steps"]  # rule 3: the study keeps its schedule
    diff = differing(recorded, asked, ignore=("steps",))
    if diff:
        unrecorded = {"window": 1}  # a term config.json leaves out at its default (TrainConfig.to_dict)

        def value(terms_: dict[str, Any], k: str) -> str:
            return json.dumps(terms_.get(k, unrecorded.get(k)))

        shown = ", ".join(f"{k} {value(recorded, k)} (asked {value(asked, k)})" for k in diff)
        raise SmspaceError(
            f"{where} holds a study with other terms: {shown}; keep them, use another --out, or pass --overwrite"
        )
    template = replace(requested, lr_decay_steps=asked["lr_decay_steps"])
    if extension is None:
        return template, None
    return template, (
        f"extending the study in {where} from {recorded['steps']} to {steps} steps on its recorded schedule "
        f"({schedule(template)})"
    )
