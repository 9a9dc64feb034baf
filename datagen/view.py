"""`smgen view`: replay a dataset in rerun on a `transition` timeline, logged column-wise."""

from __future__ import annotations

import json

import numpy as np

from smspace.common.rerun_output import ViewOutput, recording
from smspace.datagen.parts import world_for
from smspace.datagen.setups import get_setup
from smspace.lake.dataset import Dataset

BLUE, ORANGE, GREY = (40, 110, 230), (240, 140, 20), (150, 150, 150)  # t, t+1, reachable


def metadata_markdown(ds: Dataset) -> str:
    m = ds.manifest
    rows = "\n".join(f"| {k} | `{v}` |" for k, v in m.summary().items())
    return (
        f"# {m.dataset_id}\n\n| field | value |\n|---|---|\n{rows}\n\n"
        f"## Generator config\n\n```json\n{json.dumps(m.config, indent=1)}\n```\n\n"
        f"## Software\n\n```json\n{json.dumps(m.software, indent=1)}\n```\n"
    )


def blueprint(images: bool, room_map: bool, walks: bool = False):
    import rerun.blueprint as rrb

    if images:
        sensors = rrb.Vertical(
            rrb.Spatial2DView(origin="sensor/s_t", name="s_t"), rrb.Spatial2DView(origin="sensor/s_t1", name="s_t1")
        )
    else:
        sensors = rrb.Vertical(
            rrb.TimeSeriesView(origin="sensor/s_t", name="s_t"), rrb.TimeSeriesView(origin="sensor/s_t1", name="s_t1")
        )
    places = [rrb.Spatial2DView(origin="ego", name="egocentric p_t (blue), p_t1 (orange), the episode's path")]
    if room_map:
        places.append(rrb.Spatial2DView(origin="map", name="room from above: camera at t, t+1"))
    return rrb.Blueprint(
        rrb.Horizontal(
            sensors,
            rrb.Vertical(*places),
            rrb.Vertical(
                *(
                    [rrb.Spatial3DView(origin="motor_path", name="the episode in motor space (first 3 motors)")]
                    if walks
                    else []
                ),
                rrb.TimeSeriesView(origin="motor", name="motors"),
                rrb.TimeSeriesView(origin="shift", name="shift (privileged)"),
                rrb.TextDocumentView(origin="dataset", name="dataset"),
            ),
        ),
        collapse_panels=True,
    )


def _series(rec, path: str, times, values: np.ndarray, names: list[str]) -> None:
    import rerun as rr

    n, k = values.shape
    rec.log(path, rr.SeriesLines(names=names), static=True)
    rec.send_columns(path, indexes=times, columns=rr.Scalars.columns(scalars=values.reshape(-1)).partition([k] * n))


def episode_paths(start: np.ndarray, end: np.ndarray, step: np.ndarray) -> list[np.ndarray]:
    """Per transition, the path its episode has taken so far: the points at steps 0 .. step and
    the one it ends at (rows of `start` and `end`, e.g. p_t and p_t1)."""
    paths = []
    for row, k in enumerate(step):
        first = row - int(k)
        paths.append(np.concatenate([start[first : row + 1], end[row : row + 1]]))
    return paths


def _log_paths(rec, times, tr, step: np.ndarray) -> None:
    """A walk's episode as a path through the egocentric sensor positions and through motor space."""
    import rerun as rr

    n = len(tr)
    ego = episode_paths(tr.p_t, tr.p_t1, step)
    rec.send_columns("ego/path", indexes=times, columns=rr.LineStrips2D.columns(strips=ego, colors=[GREY] * n))
    k = min(3, tr.m_t.shape[1])
    motor = [np.pad(p, ((0, 0), (0, 3 - k))) for p in episode_paths(tr.m_t[:, :k], tr.m_t1[:, :k], step)]
    rec.send_columns("motor_path/path", indexes=times, columns=rr.LineStrips3D.columns(strips=motor, colors=[BLUE] * n))
    now = np.pad(tr.m_t1[:, :k], ((0, 0), (0, 3 - k)))
    rec.send_columns(
        "motor_path/now",
        indexes=times,
        columns=rr.Points3D.columns(positions=now, colors=[ORANGE] * n, radii=[0.03] * n),
    )


def view_dataset(ds: Dataset, limit: int | None, output: ViewOutput) -> int:
    import rerun as rr

    tr, walks = ds.read_walk(limit)
    n = len(tr)
    images = tr.s_t.dtype == np.uint8
    setup = get_setup(ds.manifest.setup)
    layout = blueprint(images, setup.view_world is not None, walks is not None)
    with recording("smspace", ds.manifest.dataset_id, layout, output, ds.local_folder) as rec:
        times = [rr.TimeColumn("transition", sequence=np.arange(n))]
        if walks is not None:
            times += [rr.TimeColumn("episode", sequence=walks[0]), rr.TimeColumn("step", sequence=walks[1])]
        rec.log("dataset", rr.TextDocument(metadata_markdown(ds), media_type=rr.MediaType.MARKDOWN), static=True)
        for name in ("s_t", "s_t1"):
            s = getattr(tr, name)
            if images:
                h, w, _ = s.shape[1:]
                fmt = rr.components.ImageFormat(width=w, height=h, color_model="RGB", channel_datatype="U8")
                rec.log(f"sensor/{name}", rr.Image.from_fields(format=fmt), static=True)
                rec.send_columns(f"sensor/{name}", indexes=times, columns=rr.Image.columns(buffer=s.reshape(n, -1)))
            else:
                _series(rec, f"sensor/{name}", times, s, [f"{name}[{i}]" for i in range(s.shape[1])])
        for name in ("m_t", "m_t1"):
            m = getattr(tr, name)
            _series(rec, f"motor/{name}", times, m, [f"{name}[{i}]" for i in range(m.shape[1])])
        _series(rec, "shift/t", times, tr.shift_t, ["shift_t x", "shift_t y"])
        _series(rec, "shift/t1", times, tr.shift_t1, ["shift_t1 x", "shift_t1 y"])
        _, p_reg = ds.regular_sampling()
        rec.log("ego/reachable", rr.Points2D(np.unique(p_reg, axis=0), colors=GREY, radii=0.03), static=True)
        for name, colour in (("p_t", BLUE), ("p_t1", ORANGE)):
            rec.send_columns(
                f"ego/{name}",
                indexes=times,
                columns=rr.Points2D.columns(positions=getattr(tr, name), colors=[colour] * n, radii=[0.06] * n),
            )
        if walks is not None:
            _log_paths(rec, times, tr, walks[1])
        if setup.view_world is not None:
            setup.view_world(rec, world_for(setup.name, ds.manifest.world_seed), tr, times)
    return n
