"""`smtrain report`: the paper's figures and a table of final values, drawn from real run folders."""

from __future__ import annotations

import csv
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import SmspaceError
from lake.dataset import Dataset
from lake.normalise import normalisers
from metrics import affine_projection
from train.run_dir import RunDir

MODE_COLOURS = {"MEM": "tab:red", "MM": "tab:green", "MME": "tab:blue"}
METRICS = (("eval_loss", "loss"), ("d_topo", "D_topo"), ("d_metric", "D_metric"))


@dataclass
class RunData:
    run: RunDir
    mode: str
    rows: list[dict[str, Any]]
    setup: str = ""
    n_h: int = 3

    @property
    def name(self) -> str:
        return self.run.name

    @property
    def study(self) -> str:
        """What may be averaged together: one setup at one N_h (modes are compared within it)."""
        return f"{self.setup or 'unknown'}-nh{self.n_h}"

    def column(self, key: str) -> np.ndarray:
        return np.array([r[key] for r in self.rows], np.float64)


def load_runs(paths: list[Path]) -> list[RunData]:
    runs = []
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
        runs.append(RunData(run, mode, rows, setup, cfg.n_h))
    return runs


def by_study(runs: list[RunData]) -> dict[str, list[RunData]]:
    groups: dict[str, list[RunData]] = defaultdict(list)
    for r in runs:
        groups[r.study].append(r)
    return dict(sorted(groups.items()))


def by_mode(runs: list[RunData]) -> dict[str, list[RunData]]:
    groups: dict[str, list[RunData]] = defaultdict(list)
    for r in runs:
        groups[r.mode].append(r)
    order = [m for m in MODE_COLOURS if m in groups] + sorted(m for m in groups if m not in MODE_COLOURS)
    return {m: groups[m] for m in order}


def curves_figure(groups: dict[str, list[RunData]], path: Path) -> None:
    """Loss, D_topo, D_metric against step: mean ± std over runs per mode, faint per-run lines."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, (key, label) in zip(axes, METRICS, strict=True):
        for mode, runs in groups.items():
            colour = MODE_COLOURS.get(mode, "tab:gray")
            length = min(len(r.rows) for r in runs)  # runs still in progress are cut to the shortest
            steps = runs[0].column("step")[:length]
            values = np.stack([r.column(key)[:length] for r in runs])
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


def projection_figure(run: RunData, path: Path) -> None:
    """Normalised regular motors, h, p with ĥ (and lines), predicted vs true s_t1 (first 3 dims)."""
    import matplotlib.pyplot as plt

    step = int(run.rows[-1]["step"])
    h, p = run.run.embeddings(step)
    h, p = h.astype(np.float64), p.astype(np.float64)
    h_hat = affine_projection(h, p)
    last = run.rows[-1]
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


def final_table(groups: dict[str, list[RunData]]) -> list[dict[str, Any]]:
    table = []
    for mode, runs in groups.items():
        row: dict[str, Any] = {"setup": runs[0].setup, "n_h": runs[0].n_h, "mode": mode, "runs": len(runs)}
        row["step"] = int(min(r.rows[-1]["step"] for r in runs))
        for key, _ in METRICS:
            values = np.array([r.rows[-1][key] for r in runs])
            row[f"{key}_mean"], row[f"{key}_std"] = float(values.mean()), float(values.std())
        table.append(row)
    return table


def _mean_std(mean: float, std: float, runs: int) -> str:
    """One run has no spread to show; "± 0" would claim one."""
    return f"{mean:.3g}" if runs == 1 else f"{mean:.3g} ± {std:.2g}"


def write_tables(runs: list[RunData], table: list[dict[str, Any]], out: Path) -> None:
    with open(out / "final.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)
    with open(out / "runs.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["run", "setup", "n_h", "mode", "step", "eval_loss", "d_topo", "d_metric"])
        for r in runs:
            last = r.rows[-1]
            writer.writerow(
                [r.name, r.setup, r.n_h, r.mode, last["step"], last["eval_loss"], last["d_topo"], last["d_metric"]]
            )
    lines = ["| setup | N_h | mode | runs | step | loss | D_topo | D_metric |", "|---|---|---|---|---|---|---|---|"]
    for row in table:
        cells = [_mean_std(row[f"{k}_mean"], row[f"{k}_std"], row["runs"]) for k, _ in METRICS]
        head = f"| {row['setup']} | {row['n_h']} | {row['mode']} | {row['runs']} | {row['step']} | "
        lines.append(head + " | ".join(cells) + " |")
    (out / "final.md").write_text("\n".join(lines) + "\n")


def report(paths: list[Path], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    runs = load_runs(paths)
    studies = by_study(runs)
    out.mkdir(parents=True, exist_ok=True)
    written, table = [], []
    for study, members in studies.items():
        # one study keeps the plain names; several are told apart by a prefix and never averaged together
        prefix = "" if len(studies) == 1 else f"{study}_"
        groups = by_mode(members)
        curves_figure(groups, out / f"{prefix}curves.png")
        written.append(out / f"{prefix}curves.png")
        for mode, group in groups.items():
            path = out / f"{prefix}projection_{mode}.png"
            projection_figure(group[0], path)
            written.append(path)
        table += final_table(groups)
    write_tables(runs, table, out)
    return [*written, out / "final.csv", out / "final.md", out / "runs.csv"]
