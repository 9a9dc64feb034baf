"""`smtrain view`: what a run learned, on a `step` timeline: h of the regular sampling coloured
by its ground-truth p, the affine projection ĥ beside p, the curves, predicted versus true s_t1."""

from __future__ import annotations

import json

import numpy as np

from smspace.common.rerun_output import ViewOutput, recording
from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.metrics import affine_projection
from smspace.train.colours import position_colours_u8
from smspace.train.run_dir import RunView


def tile(frames: np.ndarray, columns: int = 4) -> np.ndarray:
    n, h, w, c = frames.shape
    rows = -(-n // columns)
    out = np.zeros((rows * h, columns * w, c), frames.dtype)
    for i, f in enumerate(frames):
        r, k = divmod(i, columns)
        out[r * h : (r + 1) * h, k * w : (k + 1) * w] = f
    return out


def blueprint(images: bool):
    import rerun.blueprint as rrb

    predictions = (
        rrb.Horizontal(
            rrb.Spatial2DView(origin="predictions/true", name="true s_t1"),
            rrb.Spatial2DView(origin="predictions/predicted", name="predicted s_t1"),
        )
        if images
        else rrb.Spatial2DView(origin="predictions", name="predicted (y) vs true (x) s_t1 components")
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="h", name="learned h (colour = ground-truth p)"),
                rrb.Spatial2DView(origin="projection", name="p (grey) → affine ĥ (colour)"),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="curves/loss", name="loss"),
                rrb.TimeSeriesView(origin="curves/d_topo", name="D_topo"),
                rrb.TimeSeriesView(origin="curves/d_metric", name="D_metric"),
            ),
            rrb.Vertical(predictions, rrb.TextDocumentView(origin="run", name="run")),
        ),
        collapse_panels=True,
    )


def view_run(run: RunView, output: ViewOutput) -> int:
    import rerun as rr

    cfg = run.config
    rows = run.metrics()
    steps = np.array([r["step"] for r in rows], np.int64)
    manifest = Dataset(cfg.dataset).manifest
    shape = tuple(manifest.sensor_shape)
    images = len(shape) == 3
    embeddings = [run.embeddings(int(s)) for s in steps]
    p = embeddings[0][1].astype(np.float64)
    n = len(p)
    with recording("smspace", f"run:{run.name}", blueprint(images), output, run.local_path) as rec:
        times = [rr.TimeColumn("step", sequence=steps)]
        text = f"# {run.name}\n\n```json\n{json.dumps(cfg.to_dict(), indent=1)}\n```\n"
        rec.log("run", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
        colours = position_colours_u8(p)
        h3 = np.stack([np.pad(h[:, :3], ((0, 0), (0, max(0, 3 - h.shape[1])))) for h, _ in embeddings])
        per_step = {"colors": np.tile(colours, (len(steps), 1))}  # one colour per point, every step
        rec.send_columns(
            "h",
            indexes=times,
            columns=rr.Points3D.columns(positions=h3.reshape(-1, 3), **per_step).partition([n] * len(steps)),
        )
        rec.log("projection/p", rr.Points2D(p, colors=(160, 160, 160), radii=0.05), static=True)
        h_hat = np.stack([affine_projection(h.astype(np.float64), p) for h, _ in embeddings])
        rec.send_columns(
            "projection/h_hat",
            indexes=times,
            columns=rr.Points2D.columns(positions=h_hat.reshape(-1, 2), **per_step).partition([n] * len(steps)),
        )
        strips = np.stack([np.stack([p, hh], axis=1) for hh in h_hat])  # (steps, n, 2, 2)
        rec.send_columns(
            "projection/lines",
            indexes=times,
            columns=rr.LineStrips2D.columns(strips=list(strips.reshape(-1, 2, 2)), **per_step).partition(
                [n] * len(steps)
            ),
        )
        for key, path in (
            ("eval_loss", "curves/loss/eval"),
            ("train_loss", "curves/loss/train"),
            ("d_topo", "curves/d_topo/value"),
            ("d_metric", "curves/d_metric/value"),
            ("lr", "curves/lr"),
        ):
            values = np.array([r[key] for r in rows], np.float64)
            rec.send_columns(path, indexes=times, columns=rr.Scalars.columns(scalars=values))
        _log_predictions(rec, run, steps, times, manifest, shape)
    return len(steps)


def _log_predictions(rec, run: RunView, steps: np.ndarray, times, manifest, shape) -> None:
    import rerun as rr

    true = run.true_s_t1()
    preds = np.stack([run.predictions(int(s)) for s in steps])
    _, s_norm = normalisers(manifest)
    if len(shape) == 3:

        def to_image(x: np.ndarray) -> np.ndarray:
            raw = np.clip(np.rint(s_norm.inverse(x)), 0, 255).astype(np.uint8)
            return tile(raw.reshape(len(x), *shape))

        rec.log("predictions/true", rr.Image(to_image(true)), static=True)
        mosaics = np.stack([to_image(pr) for pr in preds])
        fmt = rr.components.ImageFormat(
            width=mosaics.shape[2], height=mosaics.shape[1], color_model="RGB", channel_datatype="U8"
        )
        rec.log("predictions/predicted", rr.Image.from_fields(format=fmt), static=True)
        rec.send_columns(
            "predictions/predicted", indexes=times, columns=rr.Image.columns(buffer=mosaics.reshape(len(steps), -1))
        )
    else:
        k = true.size
        rec.log("predictions/diagonal", rr.LineStrips2D([[[-1, -1], [1, 1]]], colors=(160, 160, 160)), static=True)
        points = np.stack([np.stack([true.reshape(-1), pr.reshape(-1)], axis=1) for pr in preds])
        rec.send_columns(
            "predictions/components",
            indexes=times,
            columns=rr.Points2D.columns(positions=points.reshape(-1, 2), radii=[0.02] * (k * len(steps))).partition(
                [k] * len(steps)
            ),
        )
