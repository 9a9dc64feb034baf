"""The command-line options of smtrain, made from the training config (train/config.py): one flag per
field marked `flag(...)`, with its default, bounds and help; choices of the registered setups and
models (for completion too)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import MISSING
from typing import TYPE_CHECKING

import click

from smspace.common.completion import complete_devices
from smspace.train.config import (
    COMPILE_CHOICES,
    LAYER_BOUNDS,
    PRECISIONS,
    finite_positive,
    flag_name,
    layers_within_bounds,
    model_names,
)

if TYPE_CHECKING:
    from smspace.train.config import TrainConfig


def int_list(ctx, param, value: str | None) -> list[int] | None:
    if value is None:
        return None
    try:
        sizes = [int(v) for v in value.split(",")]  # "150,,50" is a typo, not two layers
    except ValueError:
        raise click.BadParameter(f"expected comma-separated layer sizes such as 150,100,50, got {value!r}") from None
    if not sizes or not layers_within_bounds(sizes):
        raise click.BadParameter(f"expected {LAYER_BOUNDS}, got {value!r}")
    return sizes


def json_object(ctx, param, value: str | None) -> dict | None:
    if value is None:
        return None
    try:
        parsed = json.loads(value, object_pairs_hook=_no_duplicate_keys)
    except ValueError as e:
        if not isinstance(e, json.JSONDecodeError):  # a key given twice: the last would silently win
            raise click.BadParameter(f"{e} in {value!r}") from None
        raise click.BadParameter(f"expected a JSON object such as '{{\"width\": 64}}', got {value!r}") from None
    if not isinstance(parsed, dict):
        raise click.BadParameter(f"expected a JSON object, got {value!r}")
    return parsed


def _no_duplicate_keys(pairs: list[tuple[str, object]]) -> dict:
    keys = [k for k, _ in pairs]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise ValueError(f"{', '.join(map(repr, twice))} given twice")
    return dict(pairs)


class PositiveFinite(click.ParamType):
    """A float > 0 that is a number (click's FloatRange lets NaN and inf through)."""

    name = "float"

    def convert(self, value, param, ctx) -> float:
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not finite_positive(x):
            self.fail(f"{value!r} is not a finite positive number", param, ctx)
        return x


POSITIVE_FINITE = PositiveFinite()


def config_options(exclude: tuple[str, ...] = ()) -> Callable:
    """One click option per TrainConfig flag field: names, defaults and help come from the config."""
    from smspace.train.config import flag_fields

    def decorate(fn: Callable) -> Callable:
        for f in reversed(flag_fields()):
            if f.name in exclude:
                continue
            default = f.default_factory() if f.default is MISSING else f.default
            help_text = f.metadata["help"]
            if isinstance(default, list):
                shown = f" [default: {','.join(map(str, default))}]" if default else ""
                option = click.option(flag_name(f), f.name, callback=int_list, default=None, help=help_text + shown)
            elif isinstance(default, dict):
                option = click.option(flag_name(f), f.name, callback=json_object, default=None, help=help_text)
            elif isinstance(default, bool):
                option = click.option(flag_name(f), f.name, is_flag=True, default=default, help=help_text)
            elif f.name == "precision":
                option = click.option(
                    flag_name(f), f.name, type=click.Choice(PRECISIONS), default=default, show_default=True,
                    help=help_text,
                )  # fmt: skip
            elif f.name == "compile":  # `--compile` alone means on, as it did before auto
                option = click.option(
                    flag_name(f), f.name, type=click.Choice(COMPILE_CHOICES), is_flag=False, flag_value="on",
                    default=default, show_default=True, help=help_text,
                )  # fmt: skip
            elif f.name == "model":
                option = click.option(
                    flag_name(f), f.name, type=click.Choice(model_names()), default=default, show_default=True,
                    help=help_text,
                )  # fmt: skip
            else:
                low, high = f.metadata["min"], f.metadata["max"]
                bounded = low is not None or high is not None
                if isinstance(default, float):
                    kind = POSITIVE_FINITE
                else:
                    kind = click.IntRange(low, high) if isinstance(default, int) and bounded else type(default)
                complete = {"shell_complete": complete_devices} if f.name == "device" else {}
                option = click.option(
                    flag_name(f), f.name, type=kind, default=default, show_default=True, help=help_text, **complete
                )
            fn = option(fn)
        return fn

    return decorate


def config_from_flags(flags: dict) -> TrainConfig:
    """A TrainConfig from parsed flags; flags left out (or layer lists not given) keep the config's defaults."""
    from smspace.train.config import TrainConfig, flag_fields

    given = {f.name: flags[f.name] for f in flag_fields() if flags.get(f.name) is not None}
    return TrainConfig(dataset="", **given)


def on_command_line(ctx: click.Context, name: str) -> bool:
    return ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE


def given_fields(ctx: click.Context) -> frozenset[str]:
    """The config fields whose flags were typed on the command line (not defaults)."""
    from smspace.train.config import flag_fields

    return frozenset(f.name for f in flag_fields() if on_command_line(ctx, f.name))
