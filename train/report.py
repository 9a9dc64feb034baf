"""`smtrain report`: the paper's figures and a table of final values, drawn from real run folders."""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.metrics import affine_projection
from smspace.train.run_dir import RunDir
from smspace.train.terms import differing, terms

MODE_COLOURS = {"MEM": "tab:red", "MM": "tab:green", "MME": "tab:blue"}
METRICS = (("eval_loss", "loss"), ("d_topo", "D_topo"), ("d_metric", "D_metric"))


@dataclass
class RunData:
    run: RunDir
    mode: str
    rows: list[dict[str, Any]]
    setup: str = ""
    n_h: int = 3
    terms: dict[str, Any] = field(default_factory=dict)  # what its study's runs share (train/terms.py)
    identity: tuple[str, int] = ("", 0)  # (dataset, seed): the same run twice is one run

    @property
    def name(self) -> str:
        return self.run.name

    def values(self, key: str, steps: list[int]) -> np.ndarray:
        """`key` at the given steps, by step (never by row position)."""
        by_step = {int(r["step"]): r[key] for r in self.rows}
        return np.array([by_step[s] for s in steps], np.float64)


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
        """What the study is, for titles: setup, N_h, worlds, steps."""
        first = self.runs[0]
        worlds = len({r.identity[0].rsplit("-", 1)[0] for r in self.runs})
        return f"{first.setup}, N_h = {first.n_h}, {worlds} world(s), {first.terms.get('steps', '?')} steps"


def load_runs(paths: list[Path]) -> list[RunData]:
    runs, seen = [], {}
    for path in paths:
        run = RunDir.open(path)
        rows = run.metrics()
        if not rows:
            raise SmspaceError(f"{path} has no evaluations yet")
        cfg = run.config
        if cfg.mode and cfg.setup:
            mode, setup = cfg.mode, cfg.setup
        else:  # run folders of smspace 0.1 lack them
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
    return runs


def _shown(value: Any) -> str:
    if isinstance(value, list):
        return "x".join(map(str, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def by_study(runs: list[RunData]) -> list[Study]:
    """Runs grouped by their terms; studies are named by setup and N_h, and where two share those,
    by the fields that tell them apart."""
    groups: dict[str, list[RunData]] = defaultdict(list)
    for r in runs:
        groups[json.dumps(r.terms, sort_keys=True, default=str)].append(r)
    members = list(groups.values())
    studies = []
    for group in members:
        first = group[0]
        differs = sorted({k for other in members if other is not group for k in differing(first.terms, other[0].terms)})
        name = f"{first.setup}-nh{first.n_h}"
        kin = [g for g in members if (g[0].setup, g[0].n_h) == (first.setup, first.n_h)]
        if len(kin) > 1:  # the same setup and N_h: the name says what else differs
            within = sorted({k for other in kin if other is not group for k in differing(first.terms, other[0].terms)})
            name += "".join(f"-{k}{_shown(first.terms.get(k))}" for k in within if k not in ("setup", "n_h"))
        common = set.intersection(*({int(row["step"]) for row in r.rows} for r in group))
        studies.append(Study(name, group, sorted(common), differs))
    return sorted(studies, key=lambda st: st.name)


def by_mode(runs: list[RunData]) -> dict[str, list[RunData]]:
    groups: dict[str, list[RunData]] = defaultdict(list)
    for r in runs:
        groups[r.mode].append(r)
    order = [m for m in MODE_COLOURS if m in groups] + sorted(m for m in groups if m not in MODE_COLOURS)
    return {m: groups[m] for m in order}


def curves_figure(study: Study, path: Path) -> None:
    """Loss, D_topo, D_metric against step: mean ± std over runs per mode, faint per-run lines; at
    the steps every run of the study reached (runs in progress are cut there)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    steps = np.array(study.steps)
    for ax, (key, label) in zip(axes, METRICS, strict=True):
        for mode, runs in by_mode(study.runs).items():
            colour = MODE_COLOURS.get(mode, "tab:gray")
            values = np.stack([r.values(key, study.steps) for r in runs])
            for v in values:
                ax.plot(steps, v, color=colour, alpha=0.15, linewidth=0.7)
            mean, std = values.mean(0), values.std(0)
            ax.plot(steps, mean, color=colour, linewidth=2, label=f"{mode} (n={len(runs)})")
            # on the log panels a band below zero means nothing: floor it at the lowest run
            lower = np.maximum(mean - std, values.min(0)) if key != "d_metric" else mean - std
            ax.fill_between(steps, lower, mean + std, color=colour, alpha=0.3)
        ax.set_xlabel("step")
        ax.set_title(label)
        if key != "d_metric":
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def projection_figure(run: RunData, step: int, path: Path) -> None:
    """Normalised regular motors, h, p with ĥ (and lines), predicted vs true s_t1 (first 3 dims)."""
    import matplotlib.pyplot as plt

    h, p = run.run.embeddings(step)
    h, p = h.astype(np.float64), p.astype(np.float64)
    h_hat = affine_projection(h, p)
    last = next(r for r in run.rows if int(r["step"]) == step)
    fig = plt.figure(figsize=(20, 5))
    ax = fig.add_subplot(1, 4, 1, projection="3d")
    try:
        ds = Dataset(run.run.config.dataset)
        m_norm, _ = normalisers(ds.manifest)
        m = m_norm(ds.regular_sampling()[0])
        ax.scatter(*np.pad(m[:, :3], ((0, 0), (0, max(0, 3 - m.shape[1])))).T, s=8, color="tab:blue")
    except SmspaceError:
        ax.text2D(0.1, 0.5, "dataset not available", transform=ax.transAxes)
    ax.set_title("motor space (normalised regular sampling)")
    ax = fig.add_subplot(1, 4, 2, projection="3d")
    h3, shown = first_three(h)
    ax.scatter(*h3.T, s=8, color="tab:red")
    ax.set_title(f"encoding space h{shown}   D_topo = {last['d_topo']:.2e}")
    ax = fig.add_subplot(1, 4, 3)
    for a, b in zip(p, h_hat, strict=True):
        ax.plot([a[0], b[0]], [a[1], b[1]], color="tab:red", linewidth=0.5, alpha=0.6)
    ax.scatter(p[:, 0], p[:, 1], facecolors="none", edgecolors="tab:blue", s=40, label="p")
    ax.scatter(h_hat[:, 0], h_hat[:, 1], color="tab:red", s=6, label="ĥ (affine fit of p on h)")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"position space   D_metric = {last['d_metric']:.3f}")
    ax = fig.add_subplot(1, 4, 4, projection="3d")
    true, pred = run.run.true_s_t1(), run.run.predictions(step)
    ax.scatter(*true[:, :3].T, facecolors="none", edgecolors="tab:green", s=40, label="true")
    ax.scatter(*pred[:, :3].T, color="m", s=10, label="predicted")
    ax.legend(fontsize=8)
    ax.set_title(f"sensory space s_t1 (first 3 dims)   loss = {last['eval_loss']:.3g}")
    fig.suptitle(f"{run.name} at step {step}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def first_three(h: np.ndarray) -> tuple[np.ndarray, str]:
    """h as 3 coordinates to draw, and how: itself (padded) up to N_h = 3, else its first three
    principal components (D_topo and D_metric always use all of h)."""
    if h.shape[1] <= 3:
        return np.pad(h, ((0, 0), (0, 3 - h.shape[1]))), ""
    centred = h - h.mean(0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    kept = float((s[:3] ** 2).sum() / max((s**2).sum(), 1e-300))
    return centred @ vt[:3].T, f" (PCA to 3 of {h.shape[1]} dims, {kept:.0%} of variance)"


def final_table(study: Study) -> list[dict[str, Any]]:
    """Mean ± std per mode at the last step every run of the study reached."""
    table = []
    for mode, runs in by_mode(study.runs).items():
        row: dict[str, Any] = {"study": study.name, "setup": runs[0].setup, "n_h": runs[0].n_h, "mode": mode}
        row |= {"runs": len(runs), "step": study.final_step}
        for key, _ in METRICS:
            values = np.array([r.values(key, [study.final_step])[0] for r in runs])
            row[f"{key}_mean"], row[f"{key}_std"] = float(values.mean()), float(values.std())
        table.append(row)
    return table


def _mean_std(mean: float, std: float, runs: int) -> str:
    """One run has no spread to show; "± 0" would claim one."""
    return f"{mean:.3g}" if runs == 1 else f"{mean:.3g} ± {std:.2g}"


def write_tables(studies: list[Study], table: list[dict[str, Any]], out: Path) -> None:
    with open(out / "final.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)
    with open(out / "runs.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["run", "study", "setup", "n_h", "mode", "step", "eval_loss", "d_topo", "d_metric"])
        for study in studies:
            for r in study.runs:
                at = [r.values(k, [study.final_step])[0] for k, _ in METRICS]
                writer.writerow([r.name, study.name, r.setup, r.n_h, r.mode, study.final_step, *at])
    lines = [
        "| study | setup | N_h | mode | runs | step | loss | D_topo | D_metric |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in table:
        cells = [_mean_std(row[f"{k}_mean"], row[f"{k}_std"], row["runs"]) for k, _ in METRICS]
        head = f"| {row['study']} | {row['setup']} | {row['n_h']} | {row['mode']} | {row['runs']} | {row['step']} | "
        lines.append(head + " | ".join(cells) + " |")
    (out / "final.md").write_text("\n".join(lines) + "\n")


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


def report(paths: list[Path], out: Path) -> tuple[list[Path], list[str]]:
    """The figures and tables of the runs, and the notices to show beside them."""
    import matplotlib

    matplotlib.use("Agg")
    studies = by_study(load_runs(paths))
    out.mkdir(parents=True, exist_ok=True)
    written, table = [], []
    for study in studies:
        # one study keeps the plain names; several are told apart by a prefix and never averaged together
        prefix = "" if len(studies) == 1 else f"{study.name}_"
        curves_figure(study, out / f"{prefix}curves.png")
        written.append(out / f"{prefix}curves.png")
        for mode, group in by_mode(study.runs).items():
            path = out / f"{prefix}projection_{mode}.png"
            projection_figure(group[0], study.final_step, path)
            written.append(path)
        table += final_table(study)
    write_tables(studies, table, out)
    return [*written, out / "final.csv", out / "final.md", out / "runs.csv"], notices(studies)
