"""The generation flags, declared once: `smgen generate` and `smtrain sweep` (which generates the
datasets it trains on) take them from here, so their types, bounds and help cannot drift apart.
A command chooses only the spelling its users know (`--mode` / `--modes`), the default and
whether the flag is required."""

from __future__ import annotations

import contextlib
from collections.abc import Callable

import click

from smspace.common.cli import MAX_WORKERS
from smspace.common.completion import comma_list_completer
from smspace.datagen.setups import SETUPS, setup_names
from smspace.lake.bounds import SEED, TRANSITIONS, WORLDS, Bounded, world_seeds
from smspace.lake.exploration import KINDS, MAX_LENGTH, MAX_STEP, WALK_LENGTH
from smspace.lake.transitions import MODES

SETUP_HELP = "; ".join(f"{s.name}: {s.description}" for s in SETUPS.values()) + "; or a setup a plugin registers"


def setup_option(required: bool = False, help: str = SETUP_HELP) -> Callable:
    return click.option("--setup", "setup_name", type=click.Choice(setup_names()), required=required, help=help)


def modes_option(flag: str, dest: str, **given) -> Callable:
    help_text = "MEM, MM, MME, several separated by commas, or all."
    return click.option(flag, dest, shell_complete=comma_list_completer(MODES), help=help_text, **given)


class BoundedInt(click.ParamType):
    """A flag read by the bounds a study file and the API are read by (lake/bounds.py), so the
    three refuse one number in the same words."""

    name = "integer"

    def __init__(self, bounds: Bounded):
        self.bounds = bounds

    def __repr__(self) -> str:
        return f"BoundedInt({self.bounds.low}..{self.bounds.high})"

    def convert(self, value, param, ctx) -> int:
        if isinstance(value, str):
            with contextlib.suppress(ValueError):  # not a number: said by the bounds, as a file's string is
                value = int(value)
        problem = self.bounds.problem(value)
        if problem is not None:
            flag = param.opts[0] if param is not None else self.name
            raise click.UsageError(f"{flag} {problem}", ctx)  # "--transitions must be positive, got 0"
        return value


def transitions_option() -> Callable:
    return click.option(
        "--transitions", type=BoundedInt(TRANSITIONS), default=None, help="Transitions per dataset [setup default]."
    )


def worlds_option(default: int) -> Callable:
    return click.option(
        "--worlds", type=BoundedInt(WORLDS), default=default, show_default=True,
        help="Number of worlds; their seeds are SEED, SEED+1, …",
    )  # fmt: skip


def first_seed_option(dest: str, help: str = "Seed of the first world.") -> Callable:
    return click.option("--seed", dest, type=BoundedInt(SEED), default=0, show_default=True, help=help)


def generator_workers_option(flag: str, dest: str) -> Callable:
    return click.option(
        flag, dest, type=click.IntRange(1, MAX_WORKERS), default=None,
        help="Generator processes [default: this machine's cores; bytes do not depend on it].",
    )  # fmt: skip


def check_seed_range(seed: int, worlds: int) -> None:
    """The last world's seed must still be a seed (both commands, before anything is written)."""
    world_seeds(seed, worlds, "--seed", "--worlds")


def exploration_options(func: Callable) -> Callable:
    """--exploration, --walk-length, --walk-step: how the generated datasets explore."""
    options = [
        click.option(
            "--exploration",
            type=click.Choice(KINDS),
            default="transitions",
            show_default=True,
            help="Independent transitions (the paper's), or episodes of a bounded random walk in motor space.",
        ),
        click.option(
            "--walk-length",
            type=click.IntRange(1, MAX_LENGTH),
            default=WALK_LENGTH,
            show_default=True,
            help="Steps per episode.",
        ),
        click.option(
            "--walk-step",
            type=click.FloatRange(0, MAX_STEP, min_open=True),
            default=None,
            help="Per step: lattice levels (grid) or a standard deviation of the motor range (arm) [the setup's].",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func
