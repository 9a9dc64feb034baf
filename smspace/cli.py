"""The two commands, assembled in one place. Each package defines its subcommands and imports nothing
above it; this module, above all of them, groups them (`smgen`, `smtrain`: pyproject's scripts)."""

from __future__ import annotations

import sys

import click

from smspace.bench import cli as bench
from smspace.common.cli import OneLineErrors
from smspace.datagen import cli as datagen
from smspace.study import cli as study
from smspace.train import cli as train

HELP = {"help_option_names": ["-h", "--help"]}


@click.group(name="smgen", cls=OneLineErrors, context_settings=HELP)
@click.version_option(package_name="smspace")
def smgen() -> None:
    """Sensorimotor datasets in an MCAP data lake."""


@click.group(name="smtrain", cls=OneLineErrors, context_settings=HELP)
@click.version_option(package_name="smspace")
def smtrain() -> None:
    """Train and inspect sensorimotor predictive networks."""


for command in datagen.COMMANDS:
    smgen.add_command(command)
for command in (*train.COMMANDS, *study.COMMANDS, *bench.COMMANDS):
    smtrain.add_command(command)


if __name__ == "__main__":  # `python -m smspace.cli …` is smtrain (how `--nproc` starts its ranks)
    sys.exit(smtrain(prog_name="smtrain"))
