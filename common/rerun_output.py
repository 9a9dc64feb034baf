"""Where a rerun recording goes: an .rrd file, a web viewer on 127.0.0.1, or a spawned viewer.

The rerun CLI binds 0.0.0.0 unless told otherwise, and killing its Python wrapper leaves the real
binary running (measured with rerun-sdk 0.41): the web viewer here is the binary itself,
bound to 127.0.0.1, in its own process group, which Ctrl-C takes down whole.
"""

from __future__ import annotations

import functools
import os
import re
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click

from smspace.common.atomic import commit, partial_path
from smspace.common.cli import check_output, die_with_parent
from smspace.common.errors import SmspaceError


@dataclass(frozen=True)
class ViewOutput:
    save: Path | None = None
    web: bool = False
    web_port: int = 9090
    grpc_port: int = 9876
    overwrite: bool = False


def view_options(fn: Callable) -> Callable:
    """The standard output flags of `smgen view` and `smtrain view`."""

    @click.option("--save", type=click.Path(path_type=Path), default=None, help="Write an .rrd file instead.")
    @click.option("--web", is_flag=True, help="Serve a web viewer on 127.0.0.1 (Ctrl-C stops it).")
    @click.option("--web-port", type=click.IntRange(1, 65535), default=9090, show_default=True)
    @click.option("--grpc-port", type=click.IntRange(1, 65535), default=9876, show_default=True)
    @click.option("--overwrite", is_flag=True, help="Replace the --save file if it exists.")
    @functools.wraps(fn)
    def wrapper(*args, save, web, web_port, grpc_port, overwrite, **kwargs):
        return fn(*args, output=ViewOutput(save, web, web_port, grpc_port, overwrite), **kwargs)

    return wrapper


def has_display() -> bool:
    """Whether a viewer window can open here (Linux needs X11 or Wayland; other systems have one)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def free_name(path: Path) -> Path:
    """`path`, or `path` with -1, -2… before its suffix where a file already has the name."""
    candidate, n = path, 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    return candidate


def rerun_binary() -> Path:
    import rerun_cli

    binary = Path(rerun_cli.__file__).parent / "rerun"
    if not binary.exists():
        raise SmspaceError(f"the rerun viewer binary is missing ({binary}); reinstall rerun-sdk")
    return binary


@contextmanager
def recording(app_id: str, recording_id: str, blueprint, output: ViewOutput, source: Path | None) -> Iterator:
    """A RecordingStream whose data ends up where the flags say; yields it for logging.

    An .rrd is written under a temporary name and renamed only once complete, so a kill or a full
    disk leaves no truncated recording; it never replaces a file without --overwrite, nor lands
    inside `source` (the dataset or run folder being shown)."""
    import rerun as rr

    save, web = output.save, output.web
    if save is not None and web:
        raise SmspaceError("choose one of --save and --web")
    if save is None and not web and not has_display():  # a viewer window cannot open: write the file
        save = free_name(Path.cwd() / f"{re.sub(r'[^A-Za-z0-9._-]+', '-', recording_id).strip('-')}.rrd")
        click.echo(
            f"smspace: note: no display here ($DISPLAY and $WAYLAND_DISPLAY unset): the recording goes to {save} "
            f"(open it with `rerun {save}` where there is one, or use --web)",
            err=True,
        )
    tmp = partial = None
    if save is not None:
        check_output(save, output.overwrite, [source])
        try:
            save.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SmspaceError(f"cannot write {save}: {e.strerror or e}") from e
    rec = rr.RecordingStream(app_id, recording_id=recording_id)
    if save is not None:
        partial = partial_path(save)
        rec.save(partial, default_blueprint=blueprint)
    elif web:
        tmp = tempfile.NamedTemporaryFile(prefix="smspace-", suffix=".rrd", delete=False)  # noqa: SIM115
        tmp.close()
        rec.save(tmp.name, default_blueprint=blueprint)
    else:
        try:
            rec.spawn(default_blueprint=blueprint)
        except Exception as e:
            raise SmspaceError(f"could not start a rerun viewer ({e}); use --save FILE.rrd or --web") from e
    try:
        yield rec
    except BaseException:
        rec.disconnect()
        if partial is not None:
            partial.unlink(missing_ok=True)
        raise
    rec.flush()
    rec.disconnect()
    if partial is not None:
        commit(partial, save)
    if tmp is not None:
        try:
            serve_web(Path(tmp.name), output.web_port, output.grpc_port)
        finally:
            Path(tmp.name).unlink(missing_ok=True)


def serve_web(rrd: Path, web_port: int = 9090, grpc_port: int = 9876) -> None:
    """Run the viewer binary on 127.0.0.1 until Ctrl-C; then stop its whole process group."""
    cmd = [
        str(rerun_binary()),
        "--web-viewer",
        "--bind",
        "127.0.0.1",
        "--web-viewer-port",
        str(web_port),
        "--port",
        str(grpc_port),
        str(rrd),
    ]
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    proc = subprocess.Popen(
        cmd,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        preexec_fn=lambda: die_with_parent(signal.SIGTERM),  # a kill -9 of smspace takes the viewer down
    )
    click.echo(f"web viewer: http://127.0.0.1:{web_port}  (Ctrl-C to stop)", err=True)
    try:
        code = proc.wait()
        if code != 0:
            raise SmspaceError(f"the rerun web viewer exited with {code}: {proc.stderr.read().decode()[-300:]}")
    except KeyboardInterrupt:
        pass
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        sys.stderr.flush()
