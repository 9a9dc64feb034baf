"""What smgen and smtrain share: one-line errors with exit code 2, and common options."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import json
import os
import signal
import sys
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path

import click

from smspace.common.errors import Interrupted, SmspaceError, one_line

LAKE_OPTION = click.option(
    "--lake",
    default=None,
    help="The lake: a folder or an fsspec URL such as s3://bucket/lake [default: $SMSPACE_LAKE or data/lake].",
)


def executor_option(what: str) -> Callable:
    """--executor of the commands that fan out: local processes (the default: nothing to install or
    start) or Ray."""
    return click.option(
        "--executor",
        type=click.Choice(EXECUTORS),
        default="local",
        show_default=True,
        help=f"Where {what}: local processes, or Ray ($RAY_ADDRESS, else a local Ray on --workers CPUs).",
    )


def fail(message: str, code: int = 2) -> None:
    prog = click.get_current_context(silent=True)
    name = prog.find_root().info_name if prog else Path(sys.argv[0]).name
    click.echo(f"{name}: error: {one_line(message, limit=2000)}", err=True)  # one line, whatever the message held
    sys.exit(code)


def friendly_errors(fn: Callable) -> Callable:
    """Our own errors become one line on stderr and their exit code (2: bad input), never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SmspaceError as e:
            if os.environ.get("SMSPACE_TRACEBACK") and e.__cause__ is not None:  # a plugin's own traceback
                traceback.print_exception(e.__cause__, file=sys.stderr)
            fail(str(e), e.exit_code)

    return wrapper


@contextlib.contextmanager
def on_interrupt(message: str) -> Iterator[None]:
    """Ctrl-C or SIGTERM inside the block ends the command with `message` (what was kept and how to
    continue) instead of a bare "interrupted"."""
    try:
        yield
    except Interrupted:
        raise
    except KeyboardInterrupt:
        raise Interrupted(message) from None


MAX_WORKERS = 1024  # processes (or Ray CPUs) one command may ask for
MAX_ENSEMBLE = 10_000  # runs in one vectorised model
DEFAULT_MAX_ENSEMBLE = 150  # runs per vectorised model unless a sweep or study says otherwise
EXECUTORS = ("local", "ray")  # where work fans out: this machine's processes, or Ray
DEFAULT_LAKE = "data/lake"


def default_lake() -> str:
    """$SMSPACE_LAKE (a folder or an fsspec URL such as s3://bucket/lake), else data/lake."""
    return os.environ.get("SMSPACE_LAKE") or DEFAULT_LAKE


def default_workers() -> int:
    """The cores this process may use: the default number of generator processes."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def echo_listing(rows: list[dict], as_json: bool, header: str, line: Callable[[dict], str]) -> None:
    """`ls` output: one JSON object per row, or a header and one formatted line per row."""
    if as_json:
        for row in rows:
            click.echo(json.dumps(row))
        return
    click.echo(header)
    for row in rows:
        click.echo(line(row))


class OneLineErrors(click.Group):
    """A command group whose usage errors (unknown flag, value out of range) are one line on
    stderr with exit code 2, like every other error of smspace, instead of click's three."""

    def main(self, *args, **kwargs):  # type: ignore[override]
        kwargs["standalone_mode"] = False
        signal.signal(signal.SIGTERM, _terminate)
        try:
            code = super().main(*args, **kwargs)
        except click.exceptions.NoArgsIsHelpError as e:  # a bare `smgen`: the help, as click prints it
            click.echo(e.format_message(), err=True)
            sys.exit(2)
        except click.UsageError as e:
            prog = kwargs.get("prog_name") or Path(sys.argv[0]).name
            click.echo(f"{prog}: error: {' '.join(e.format_message().split())}", err=True)
            sys.exit(2)
        except click.Abort as e:  # Ctrl-C or SIGTERM: whatever the command started is stopped by now
            cause = e.__cause__
            click.echo(cause.message if isinstance(cause, Interrupted) else "interrupted", err=True)
            sys.exit(130)
        sys.exit(code if isinstance(code, int) else 0)


def display_name(name: str) -> str:
    """A file name as printable text, whatever bytes it holds (names are not always UTF-8)."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def check_output(out: Path, overwrite: bool, inputs: list[Path | None]) -> None:
    """An output file may replace an existing file only with --overwrite, and never lands inside
    what the command reads (a dataset or run folder), --overwrite or not."""
    out = Path(out)
    if out.is_dir():
        raise SmspaceError(f"{out} is a folder; give a file name")
    resolved = out.resolve()
    for folder in filter(None, inputs):  # None: an input on object storage, never a local parent
        if resolved.is_relative_to(Path(folder).resolve()):
            raise SmspaceError(f"{out} is inside {folder}, which this command reads; write it elsewhere")
    if out.exists() and not overwrite:
        raise SmspaceError(f"{out} exists; pass --overwrite to replace it")


def die_with_parent(sig: int = signal.SIGKILL, parent: int | None = None) -> None:
    """In a child process: the kernel sends `sig` when the parent dies, however it dies (Linux),
    so workers and viewers never outlive the command that started them. `parent`: the pid the child
    was started by; if it is already gone (it died while the child was starting), exit now."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, int(sig), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the parent's own cleanup is all there is
        pass
    if parent is not None and os.getppid() != parent:
        os._exit(1)


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM cleans up exactly as Ctrl-C does
