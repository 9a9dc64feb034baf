"""`smtrain report`: the paper's figures and a table of final values, drawn from real run folders."""

from __future__ import annotations

import csv
import io
import json
import re
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smspace.common.differing import differing
from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.lake.store import StorageUnreachable, exists, where
from smspace.lake.transitions import MODES
from smspace.metrics import affine_projection
from smspace.metrics.scores import SCORES
from smspace.metrics.spatial import DegenerateRepresentation
from smspace.metrics.spread import Spread, along, as_cell, grouped
from smspace.train.colours import position_colours
from smspace.train.pages import escape, record_files, recorded_files, refuse_inside, save_figure, write_text
from smspace.train.run_dir import RunView
from smspace.train.terms import terms

MODE_COLOURS = {"MEM": "tab:red", "MM": "tab:green", "MME": "tab:blue"}
# what a report shows of each evaluation: the loss, and the scores metrics/scores.py declares
METRICS = (("eval_loss", "loss"), *((name, SCORES[name].title) for name in ("d_topo", "d_metric")))
FROM_SAVED_H = ("probe_r2", "local_dim")  # the bench's other scores, measured on the h an evaluation saved
COLUMNS = (*METRICS, *((name, SCORES[name].title) for name in FROM_SAVED_H))  # the tables' (figures: METRICS)


@dataclass
class RunData:
    run: RunView
    mode: str
    rows: list[dict[str, Any]]
    setup: str = ""
    n_h: int = 3
    terms: dict[str, Any] = field(default_factory=dict)  # what its study's runs share (train/terms.py)
    identity: tuple[str, int] = ("", 0)  # (dataset, seed): the same run twice is one run
    measured: dict[tuple[str, int], float] = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        return self.run.name

    def values(self, key: str, steps: list[int]) -> np.ndarray:
        """`key` at the given steps, by step (never by row position): a recorded metric, or a score
        measured here on the h saved at that step, as smspace-bench measures it (metrics/scores.py,
        the probe's folds drawn from the run's world seed)."""
        if key in FROM_SAVED_H:
            return np.array([self._measured(key, s) for s in steps], np.float64)
        by_step = {int(r["step"]): r[key] for r in self.rows}
        return np.array([by_step[s] for s in steps], np.float64)

    def _measured(self, key: str, step: int) -> float:
        if (key, step) not in self.measured:  # the step's h read once for all its scores
            h, p = self.run.embeddings(step)
            for name in FROM_SAVED_H:
                try:
                    self.measured[name, step] = float(SCORES[name].compute(h, p, self.run.config.seed))
                except DegenerateRepresentation:  # a collapsed h has no dimension nor probe: said as NaN
                    self.measured[name, step] = float("nan")
        return self.measured[key, step]


@dataclass
class Study:
    """Runs that may be averaged together: every term shared but dataset, mode and seed."""

    name: str
    runs: list[RunData]
    steps: list[int]  # the evaluation steps every run reached, so every mean is of one step
    differs: list[str] = field(default_factory=list)  # what sets it apart from the others reported

    @property
    def final_step(self) -> int:
        return self.steps[-1]

    @property
    def label(self) -> str:
        """What the study is, for titles: setup, N_h, the network and its precision, worlds, steps."""
        first = self.runs[0]
        worlds = len({r.identity[0].rsplit("-", 1)[0] for r in self.runs})
        return (
            f"{first.setup}, N_h = {first.n_h}, {worlds} world(s), {first.terms.get('steps', '?')} steps; "
            f"{network_label(first.terms)}"
        )

    @property
    def file_stem(self) -> str:
        """The study's name as a file name any Markdown viewer links to (no spaces, quotes or braces)."""
        return safe_name(self.name)

    def value(self, variable: str) -> Any:
        """The value of a grid variable (a term) in this study."""
        return self.runs[0].terms.get(variable)


def network_label(terms: dict[str, Any]) -> str:
    """The network a run trains and how: model, its parameters, precision (fp32 unless recorded)."""
    params = terms.get("model_params") or {}
    shown = f" ({', '.join(f'{k}={v}' for k, v in sorted(params.items()))})" if params else ""
    return f"{terms.get('model', 'sensorimotor')}{shown}, {terms.get('precision', 'fp32')}"


def safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=-]+", "_", name).strip("_") or "study"


def load_runs(paths: list[Path], left_out: list[str] | None = None) -> list[RunData]:
    """The runs to report; a run with no evaluation (failed or stopped before its first) is left
    out and named in `left_out`, so one bad run hides none of the others."""
    runs, seen, skipped = [], {}, []
    for path in paths:
        run = RunView.open(path)
        rows = run.metrics()
        if not rows:
            status = run.status()
            why = f"{status.state}: {status.message}" if status.message else status.state
            skipped.append(f"{path} has no evaluations yet ({why})")
            continue
        cfg = run.config
        if cfg.mode and cfg.setup:
            mode, setup = cfg.mode, cfg.setup
        else:  # configs written before they recorded them lack them
            manifest = Dataset(cfg.dataset).manifest
            mode, setup = manifest.mode, manifest.setup
        recorded = run.recorded_keys()
        data = RunData(
            run,
            mode,
            rows,
            setup,
            cfg.n_h,
            {k: v for k, v in terms(cfg).items() if k in recorded} | {"setup": setup},
            (cfg.dataset_id or cfg.dataset, cfg.seed),
        )
        twin = seen.get((data.identity, json.dumps(data.terms, sort_keys=True)))
        if twin is not None:
            raise SmspaceError(
                f"{path} and {twin} are the same run (dataset {data.identity[0]}, seed {data.identity[1]}, "
                "same terms); report each run once"
            )
        seen[(data.identity, json.dumps(data.terms, sort_keys=True))] = path
        runs.append(data)
    if not runs:
        raise SmspaceError(skipped[0] if len(skipped) == 1 else f"no run has evaluations yet: {'; '.join(skipped)}")
    if left_out is not None:
        left_out += skipped
    return runs


def _shown(value: Any) -> str:
    if isinstance(value, list):
        return "x".join(map(str, value))
    if isinstance(value, dict):
        return ",".join(f"{k}={_shown(v)}" for k, v in sorted(value.items())) or "{}"
    return f"{value:g}" if isinstance(value, float) else str(value)


def by_study(runs: list[RunData]) -> list[Study]:
    """Runs grouped by their terms; studies are named by setup and N_h, and where two share those,
    by the fields that tell them apart."""
    members = list(grouped(runs, lambda r: json.dumps(r.terms, sort_keys=True, default=str)).values())
    variables = independent([g[0].terms for g in members])
    studies = []
    for group in members:
        first = group[0]
        differs = sorted({k for other in members for k in differing(first.terms, other[0].terms, within=variables)})
        name = f"{first.setup}-nh{first.n_h}"
        kin = [g for g in members if (g[0].setup, g[0].n_h) == (first.setup, first.n_h)]
        if len(kin) > 1:  # the same setup and N_h: the name says what else differs
            within = sorted({k for g in kin for k in differing(first.terms, g[0].terms, within=differs)})
            name += "".join(f"-{k}{_shown(first.terms.get(k))}" for k in within if k not in ("setup", "n_h"))
        common = set.intersection(*({int(row["step"]) for row in r.rows} for r in group))
        studies.append(Study(name, group, sorted(common), differs))
    return sorted(studies, key=lambda st: st.name)


FIRST = ("setup", "model", "n_h")  # the variables a reader names a combination by, in this order


def independent(terms: list[dict[str, Any]]) -> list[str]:
    """The terms that tell studies apart, less those setup, model or N_h already imply (a setup's
    own encoder layers, a model's plugin record): what a reader would name a combination by."""
    keys = sorted({k for a in terms for b in terms for k in differing(a, b)})
    named = [k for k in FIRST if k in keys]

    def parts(names: list[str]) -> int:
        return len({json.dumps([t.get(k) for k in names], sort_keys=True, default=str) for t in terms})

    implied = {k for k in keys if k not in FIRST and named and parts([*named, k]) == parts(named)}
    return [k for k in keys if k not in implied]


def by_mode(runs: list[RunData]) -> dict[str, list[RunData]]:
    return grouped(runs, lambda r: r.mode, MODES)


POSITION_UNITS = {"grid": "cells", "grid6": "cells", "arm": "m", "arm6": "m"}  # docs/MODEL.md §2
AXIS_LABELS = {
    "eval_loss": "evaluation loss (summed squared error)",
    "d_topo": "D_topo (lower: topology kept)",
    "d_metric": "D_metric (lower: metric kept)",
}


def position_unit(setup: str) -> str:
    return POSITION_UNITS.get(setup, "the setup's units")


def curves_figure(study: Study, path: Path) -> None:
    """Loss, D_topo, D_metric against step: mean ± std over runs per mode, faint per-run lines; at
    the steps every run of the study reached (runs in progress are cut there)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    steps = np.array(study.steps)
    handles = []
    for ax, (key, label) in zip(axes, METRICS, strict=True):
        handles = []
        for mode, runs in by_mode(study.runs).items():
            colour = MODE_COLOURS.get(mode, "tab:gray")
            values = np.stack([r.values(key, study.steps) for r in runs])
            for v in values:
                ax.plot(steps, v, color=colour, alpha=0.15, linewidth=0.7)
            mean, std = along(values)
            legend = f"{mode} (mean of {len(runs)} run(s) ± std)"
            (line,) = ax.plot(steps, mean, color=colour, linewidth=2, label=legend)
            handles.append(line)
            # on the log panels a band below zero means nothing: floor it at the lowest run
            lower = np.maximum(mean - std, values.min(0)) if key != "d_metric" else mean - std
            ax.fill_between(steps, lower, mean + std, color=colour, alpha=0.3)
        ax.set_xlabel("training step")
        ax.set_ylabel(AXIS_LABELS[key])
        ax.set_title(label)
        if key != "d_metric":
            ax.set_yscale("log")
        else:  # values that barely move read as values, not as "1e-7 + 3.768e-2" offsets
            ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(alpha=0.3, which="both")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useMathText=True)
    fig.suptitle(f"{study.name}: {study.label}", fontsize=13)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 0.95))
    save_figure(fig, path, dpi=120)


def comparison_variables(studies: list[Study]) -> list[str]:
    """The terms some reported studies differ in: each gets a figure comparing them."""
    return sorted({k for st in studies for k in st.differs})


def comparison_figure(studies: list[Study], variable: str, path: Path) -> None:
    """Each metric at the last step against one grid variable: a line per mode (and per value of
    the other variables, told apart by marker), the mean over worlds with its std as error bars."""
    import matplotlib.pyplot as plt

    values = sorted({json.dumps(st.value(variable), sort_keys=True) for st in studies})
    parsed = [json.loads(v) for v in values]
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in parsed)
    if numeric:
        parsed.sort()
        values = [json.dumps(v) for v in parsed]
    others = [k for k in comparison_variables(studies) if k != variable]
    lines: dict[tuple[str, str], list[tuple[float, float, float]]] = defaultdict(list)
    for st in studies:
        rest = ", ".join(f"{k}={_shown(st.value(k))}" for k in others)
        x = st.value(variable) if numeric else values.index(json.dumps(st.value(variable), sort_keys=True))
        for mode, runs in by_mode(st.runs).items():
            finals = np.array([[r.values(k, [st.final_step])[0] for k, _ in METRICS] for r in runs])
            lines[(mode, rest)].append((float(x), *[_mean_and_std(finals[:, i]) for i in range(3)]))
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    markers, rests = "osD^vP*X", sorted({rest for _, rest in lines})
    for i, (ax, (key, label)) in enumerate(zip(axes, METRICS, strict=True)):
        for (mode, rest), points in sorted(lines.items()):
            points.sort()
            xs = [pt[0] for pt in points]
            means, stds = [pt[1 + i][0] for pt in points], [pt[1 + i][1] for pt in points]
            name = f"{mode}, {rest}" if rest else mode
            ax.errorbar(xs, means, yerr=stds, color=MODE_COLOURS.get(mode, "tab:gray"), capsize=3,
                        marker=markers[rests.index(rest) % len(markers)], label=name)  # fmt: skip
        if numeric and min(parsed) > 0 and max(parsed) / min(parsed) >= 100:
            ax.set_xscale("log")
        if numeric and all(isinstance(v, int) for v in parsed):
            ax.set_xticks(parsed)
        if not numeric:
            ax.set_xticks(range(len(values)), [_shown(v)[:28] for v in parsed], rotation=20, ha="right", fontsize=8)
        if key != "d_metric":
            ax.set_yscale("log")
        else:
            ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_xlabel(variable)
        ax.set_ylabel(AXIS_LABELS[key])
        ax.set_title(f"{label} at the last step")
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), frameon=False, fontsize=9)
    fig.suptitle(f"the studies against {variable}: mean over worlds ± std", fontsize=13)
    fig.tight_layout(rect=(0, 0.1 + 0.04 * (len(labels) // 4), 1, 0.95))
    save_figure(fig, path, dpi=110)


def projection_figure(run: RunData, step: int, path: Path) -> None:
    """Motor space, h and p with ĥ, every point coloured by its position p; and the predicted s_t1
    against the true one (image mosaics for a camera)."""
    import matplotlib.pyplot as plt

    h, p = run.run.embeddings(step)
    h, p = h.astype(np.float64), p.astype(np.float64)
    h_hat = affine_projection(h, p)
    colours = position_colours(p)
    unit = position_unit(run.setup)
    last = next(r for r in run.rows if int(r["step"]) == step)
    fig = plt.figure(figsize=(21, 5.6))
    dataset = _dataset(run)
    ax = fig.add_subplot(1, 4, 1, projection="3d")
    motors = ""
    if dataset is not None:
        m_norm, _ = normalisers(dataset.manifest)
        m3, motors = first_three(m_norm(dataset.regular_sampling()[0]))  # 4 or 6 motors: their PCA
        ax.scatter(*m3.T, s=10, c=colours)
        _axis_labels(ax, ["PC1", "PC2", "PC3"] if motors else ["m1", "m2", "m3"], "(normalised)")
    else:
        ax.text2D(0.1, 0.5, "dataset not available here", transform=ax.transAxes)
    ax.set_title(f"motor space: regular sampling{motors}")
    if h.shape[1] <= 2:  # N_h = 2 (or 1) is drawn flat: a third axis would be empty
        ax = fig.add_subplot(1, 4, 2)
        h2 = np.pad(h, ((0, 0), (0, 2 - h.shape[1])))
        ax.scatter(h2[:, 0], h2[:, 1], s=10, c=colours)
        ax.set_xlabel("h1")
        ax.set_ylabel("h2" if h.shape[1] == 2 else "(N_h = 1)")
        ax.set_title(f"encoding space h\nD_topo = {last['d_topo']:.2e}")
    else:
        ax = fig.add_subplot(1, 4, 2, projection="3d")
        h3, shown = first_three(h)
        ax.scatter(*h3.T, s=10, c=colours)
        _axis_labels(ax, ["PC1", "PC2", "PC3"] if shown else ["h1", "h2", "h3"], "")
        ax.set_title(f"encoding space h{shown}\nD_topo = {last['d_topo']:.2e}")
    ax = fig.add_subplot(1, 4, 3)
    for a, b in zip(p, h_hat, strict=True):
        ax.plot([a[0], b[0]], [a[1], b[1]], color="0.6", linewidth=0.5)
    ax.scatter(p[:, 0], p[:, 1], facecolors="none", edgecolors=colours, s=60, linewidths=1.2, label="p (true position)")
    ax.scatter(h_hat[:, 0], h_hat[:, 1], c=colours, s=10, label="ĥ (best affine image of h)")
    ax.set_aspect("equal", adjustable="datalim")  # a setup whose positions lie on a line keeps a full-size box
    ax.set_xlabel(f"p_x ({unit})")
    ax.set_ylabel(f"p_y ({unit})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=8, frameon=False)
    ax.set_title(f"position space\nD_metric = {last['d_metric']:.3f} {unit}")
    true, pred = run.run.true_s_t1(), run.run.predictions(step)
    shape = list(dataset.manifest.sensor_shape) if dataset is not None else None
    if shape is not None and len(shape) == 3 and shape[-1] in (1, 3):
        _image_mosaic(fig.add_subplot(1, 4, 4), true, pred, shape, dataset)
    else:
        _prediction_scatter(fig.add_subplot(1, 4, 4), true, pred)
    fig.axes[-1].set_title(f"s_t1, predicted against true\nevaluation loss = {last['eval_loss']:.3g}")
    fig.suptitle(
        f"{run.name} at step {step} ({run.setup}, N_h = {run.n_h}, {network_label(run.terms)}, {run.mode}): "
        "every point coloured by its position p (red grows with p_x, blue with p_y)",
        fontsize=12,
    )
    fig.subplots_adjust(left=0.02, right=0.98, top=0.83, bottom=0.14, wspace=0.25)
    save_figure(fig, path, dpi=110)


def _dataset(run: RunData) -> Dataset | None:
    try:
        return Dataset(run.run.config.dataset)
    except StorageUnreachable:
        raise
    except SmspaceError:
        return None


def _axis_labels(ax, names: list[str], unit: str) -> None:
    ax.set_xlabel(f"{names[0]} {unit}".strip(), labelpad=-2)
    ax.set_ylabel(f"{names[1]} {unit}".strip(), labelpad=-2)
    ax.set_zlabel(f"{names[2]} {unit}".strip(), labelpad=-2)
    ax.tick_params(labelsize=7, pad=0)


def _prediction_scatter(ax, true: np.ndarray, pred: np.ndarray) -> None:
    """Each sensor component: predicted against true (normalised); on the diagonal when right."""
    dims = true.shape[1]
    for d in range(min(dims, 8)):
        ax.scatter(true[:, d], pred[:, d], s=8, alpha=0.6, label=f"s[{d}]")
    lim = [min(true.min(), pred.min()) - 0.05, max(true.max(), pred.max()) + 0.05]
    ax.plot(lim, lim, color="0.3", linewidth=0.8, linestyle="--")
    ax.set_xlabel("true s_t1 (normalised)")
    ax.set_ylabel("predicted s_t1 (normalised)")
    ax.set_aspect("equal")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=min(dims, 8), fontsize=8, frameon=False)


def _image_mosaic(ax, true: np.ndarray, pred: np.ndarray, shape: list[int], dataset: Dataset, n: int = 8) -> None:
    """The first n evaluation transitions in raw pixels, in blocks of four: a row of true images
    above the row of their predictions."""
    _, s_norm = normalisers(dataset.manifest)
    n = min(n, len(true))
    pixels = [np.clip(s_norm.inverse(x[:n]), 0, 255).reshape(n, *shape) / 255.0 for x in (true, pred)]
    height, width, channels = shape
    per_row = min(4, n)

    def row(images: np.ndarray) -> np.ndarray:
        tiles = [np.pad(img, ((1, 1), (1, 1), (0, 0)), constant_values=1.0) for img in images]
        tiles += [np.ones_like(tiles[0])] * (per_row - len(tiles))
        return np.concatenate(tiles, 1)

    rows, ticks, names = [], [], []
    for start in range(0, n, per_row):
        for label, images in (("true", pixels[0]), ("predicted", pixels[1])):
            ticks.append(sum(r.shape[0] for r in rows) + (height + 2) / 2)
            names.append(f"{label} {start}-{min(start + per_row, n) - 1}")
            rows.append(row(images[start : start + per_row]))
        rows.append(np.ones((4, rows[-1].shape[1], channels)))
    ax.imshow(np.concatenate(rows[:-1], 0).squeeze(), interpolation="nearest")
    ax.set_yticks(ticks, names, fontsize=8)
    ax.set_xticks([])
    ax.set_xlabel(f"the first {n} evaluation transitions, {height}x{width} pixels each")


def first_three(h: np.ndarray) -> tuple[np.ndarray, str]:
    """h as 3 coordinates to draw, and how: itself (padded) up to N_h = 3, else its first three
    principal components (D_topo and D_metric always use all of h)."""
    if h.shape[1] <= 3:
        return np.pad(h, ((0, 0), (0, 3 - h.shape[1]))), ""
    centred = h - h.mean(0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    kept = float((s[:3] ** 2).sum() / max((s**2).sum(), 1e-300))
    return centred @ vt[:3].T, f" (PCA to 3 of {h.shape[1]} dims, {kept:.0%} of variance)"


def grid_variables(studies: list[Study]) -> list[str]:
    """The terms the reported studies differ in (a grid's variables), beyond setup and N_h, which
    every table shows anyway."""
    return sorted({k for st in studies for k in st.differs} - {"setup", "n_h"})


def cell(value: Any) -> Any:
    """A term as one table cell: numbers and strings as they are, lists and objects as JSON."""
    return json.dumps(value, sort_keys=True) if isinstance(value, list | dict) else value


def final_table(study: Study, variables: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Mean ± std per mode at the last step every run of the study reached, with the study's value
    of each grid variable."""
    table = []
    for mode, runs in by_mode(study.runs).items():
        row: dict[str, Any] = {"study": study.name, "setup": runs[0].setup, "n_h": runs[0].n_h, "mode": mode}
        row |= {"runs": len(runs), "step": study.final_step} | {v: cell(study.value(v)) for v in variables}
        for key, _ in COLUMNS:
            spread = Spread.of([r.values(key, [study.final_step])[0] for r in runs])
            row[f"{key}_mean"], row[f"{key}_std"] = spread.mean, spread.std
        table.append(row)
    return table


def _metric_columns() -> str:
    """The metrics' column titles, each with the direction its score declares (D_topo ↓), as the
    leaderboard's headings have them."""
    return " | ".join(f"{title} {SCORES[key].arrow}".rstrip() if key in SCORES else title for key, title in COLUMNS)


def _mean_and_std(values: np.ndarray) -> tuple[float, float]:
    """For an error bar: one world draws none."""
    spread = Spread.of(values)
    return spread.mean, spread.std or 0.0


def write_tables(studies: list[Study], table: list[dict[str, Any]], out: Path, variables: Sequence[str] = ()) -> None:
    final = io.StringIO(newline="")
    writer = csv.DictWriter(final, fieldnames=list(table[0]))
    writer.writeheader()
    writer.writerows(table)
    write_text(out / "final.csv", final.getvalue())
    runs = io.StringIO(newline="")
    writer = csv.writer(runs)
    writer.writerow(["run", "path", "study", "setup", "n_h", *variables, "mode", "step",
                     *(key for key, _ in COLUMNS)])  # fmt: skip
    for study in studies:
        grid = [cell(study.value(v)) for v in variables]
        for r in study.runs:
            at = [r.values(k, [study.final_step])[0] for k, _ in COLUMNS]
            writer.writerow([r.name, r.run.url, study.name, r.setup, r.n_h, *grid, r.mode, study.final_step, *at])
    write_text(out / "runs.csv", runs.getvalue())
    extra = "".join(f" {v} |" for v in variables)
    lines = [
        f"| study | setup | N_h | mode | runs | step |{extra} {_metric_columns()} |",
        "|---|---|---|---|---|---|" + "---|" * (len(variables) + len(COLUMNS)),
    ]
    for row in table:
        cells = [as_cell(row[f"{k}_mean"], row[f"{k}_std"]) for k, _ in COLUMNS]
        head = f"| {escape(row['study'])} | {row['setup']} | {row['n_h']} | {row['mode']} | "
        head += f"{row['runs']} | {row['step']} | "
        head += "".join(f"{escape(str(row[v]))} | " for v in variables)
        lines.append(head + " | ".join(cells) + " |")
    write_text(out / "final.md", "\n".join(lines) + "\n")


def notices(studies: list[Study]) -> list[str]:
    """What the reader must know about how the runs were grouped and cut, one line each."""
    lines = []
    if len(studies) > 1:
        fields = sorted({k for st in studies for k in st.differs})
        lines.append(
            f"report: {len(studies)} studies, kept apart (never averaged together): they differ in {', '.join(fields)}"
        )
    for st in studies:
        ahead = [r.name for r in st.runs if int(r.rows[-1]["step"]) > st.final_step]
        if ahead:
            lines.append(
                f"report: {st.name}: shown up to step {st.final_step}, the last every run reached "
                f"({len(ahead)} run(s) are further along)"
            )
    return lines


def expand_runs(paths: list[Path | str]) -> list[Path | str]:
    """Run folders, given themselves or by the folder of a study that holds them (its runs, and
    those of its grid's sub-folders); anything else is refused in one line."""
    from smspace.lake.scan import folders_holding
    from smspace.lake.store import open_store
    from smspace.train.run_dir import CONFIG

    found: list[Path | str] = []
    for path in paths:
        store = open_store(path)
        if store.is_file():
            raise SmspaceError(f"{path} is a file, not a run folder or a study folder")
        if exists(store, CONFIG):
            found.append(path)
            continue
        runs = [f"{where(store)}/{name}" for name in folders_holding(store, CONFIG, itself=False)]
        if not runs:
            raise SmspaceError(f"{path} holds no run folders (no {CONFIG} in it or below)")
        found += [Path(r) if isinstance(where(store), Path) else r for r in runs]
    return found


def made_with(runs: list[RunData]) -> list[str]:
    """The software and machines behind the runs and their datasets, as distinct values."""
    sessions = [s for r in runs for s in r.run.config.sessions]
    lines = []
    for key, label in (("smspace", "smspace"), ("git_commit", "git commit"), ("torch", "torch"),
                       ("python", "Python"), ("cpu", "CPU"), ("torch_cpu_capability", "torch CPU kernels"),
                       ("device", "device"), ("compile", "--compile")):  # fmt: skip
        values = sorted({str(s.get(key)) for s in sessions if s.get(key) is not None})
        if values:
            lines.append(f"- {label}: {', '.join(values)}")
    if not sessions:
        lines.append("- training sessions: not recorded (runs of an older smspace)")
    software: dict[str, set[str]] = defaultdict(set)
    for r in runs:
        dataset = _dataset(r)
        for key, value in (dataset.manifest.software if dataset is not None else {}).items():
            software[key].add(str(value))
    if software:
        shown = "; ".join(f"{k} {', '.join(sorted(v))}" for k, v in software.items())
        lines.append(f"- datasets made with: {shown}")
    return lines


def markdown_report(
    studies: list[Study],
    table: list[dict[str, Any]],
    figures: dict[str, list[Path]],
    notes: list[str],
    out: Path,
    compared: Sequence[Path] = (),
) -> Path:
    """report.md: one page per report, the comparison of the studies, then the tables and the
    figures of every study. Image links are plain file names (train/report.py, safe_name)."""
    lines = ["# smspace report", ""]
    runs = sum(len(st.runs) for st in studies)
    lines += [f"{runs} run(s) in {len(studies)} study(ies), drawn by `smtrain report`.", ""]
    lines += [f"> {note.removeprefix('report: ')}" for note in notes] + ([""] if notes else [])
    if compared:
        lines += ["## The studies compared", ""]
        varied = comparison_variables(list(studies))
        lines += [
            f"The studies differ in {', '.join(varied)}: each a column of final.csv and runs.csv, each a figure.",
            "",
        ]
        for figure in compared:
            lines += [f"![{figure.stem}]({figure.name})", ""]
    for study in studies:
        lines += [f"## {study.name}: {study.label}", ""]
        lines += [f"| mode | runs | step | {_metric_columns()} |", "|---|---|---|" + "---|" * len(COLUMNS)]
        for row in (r for r in table if r["study"] == study.name):
            cells = [as_cell(row[f"{k}_mean"], row[f"{k}_std"]) for k, _ in COLUMNS]
            lines.append(f"| {row['mode']} | {row['runs']} | {row['step']} | " + " | ".join(cells) + " |")
        lines += ["", "Mean ± standard deviation over the runs (one world each) at the last step all reached.", ""]
        for figure in figures[study.name]:
            lines += [f"![{figure.stem}]({figure.name})", ""]
        lines += [
            "### Runs",
            "",
            f"| run | mode | step | {_metric_columns()} |",
            "|---|---|---|" + "---|" * len(COLUMNS),
        ]
        for r in study.runs:
            at = [r.values(k, [study.final_step])[0] for k, _ in COLUMNS]
            lines.append(
                f"| {escape(r.name)} | {r.mode} | {study.final_step} | " + " | ".join(f"{v:.3g}" for v in at) + " |"
            )
        lines += ["", "### Made with", "", *made_with(study.runs), ""]
    path = out / "report.md"
    write_text(path, "\n".join(lines))
    return path


RECORD = ".smspace-report.json"  # the files the last report wrote here: replaced, never left stale


def report(paths: list[Path], out: Path) -> tuple[list[Path], list[str]]:
    """The figures and tables of the runs (given as run folders or study folders), the one-page
    report.md that holds them, and the notices to show beside them (runs left out among them)."""
    import matplotlib

    matplotlib.use("Agg")
    left_out: list[str] = []
    studies = by_study(load_runs(expand_runs(paths), left_out))
    refuse_inside(out, paths)
    out.mkdir(parents=True, exist_ok=True)
    earlier = recorded_files(out, RECORD)
    written, table, figures = [], [], {}
    variables = grid_variables(studies)
    compared = []
    if len(studies) > 1:
        for variable in comparison_variables(studies):
            path = out / f"compare_{safe_name(variable)}.png"
            comparison_figure(studies, variable, path)
            compared.append(path)
    for study in studies:
        # one study keeps the plain names; several are told apart by a prefix and never averaged together
        prefix = "" if len(studies) == 1 else f"{study.file_stem}_"
        figures[study.name] = [out / f"{prefix}curves.png"]
        curves_figure(study, figures[study.name][0])
        for mode, group in by_mode(study.runs).items():
            path = out / f"{prefix}projection_{mode}.png"
            projection_figure(group[0], study.final_step, path)
            figures[study.name].append(path)
        written += figures[study.name]
        table += final_table(study, variables)
    write_tables(studies, table, out, variables)
    notes = [f"report: left out {line}" for line in left_out] + notices(studies)
    page = markdown_report(studies, table, figures, notes, out, compared)
    files = [*compared, *written, out / "final.csv", out / "final.md", out / "runs.csv", page]
    record_files(out, RECORD, earlier, files)  # an earlier report's figures of studies gone now: removed
    return files, notes
