"""The ambiguity study, read back: each world's measured view ambiguity beside its runs' final
D_topo and D_metric, per level and per mode, a figure of the metrics against ambiguity, and
previews of each level. Writes into --out: ambiguity.json, ambiguity.md, ambiguity.png and
previews.png. Uses only smspace's Python API and this plugin.

Usage: python examples/ambiguous-room/analyse.py --runs runs/ambiguity --lake data/ambiguity \
           --out docs/reproduction/ambiguity
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import smspace
from smspace.metrics.ambiguity import FAR, K, spearman, view_ambiguity

MODE_COLOURS = {"MM": "tab:green", "MME": "tab:blue"}
LEVEL_MARKERS = {"ambig0": "o", "ambig1": "s", "ambig2": "^", "ambig3": "D"}
LEVEL_NAMES = {
    "ambig0": "0: smspace's room",
    "ambig1": "1: open floor, no repeat",
    "ambig2": "2: repeats every 1.5 m",
    "ambig3": "3: repeats every 0.75 m",
}
VIEWS = 1024  # MM views per world for the ambiguity measure (the first of each MM dataset)


def runs_of(folder: Path) -> list[smspace.Run]:
    return [smspace.open_run(p.parent) for p in sorted(folder.glob("*/*/config.json"))]


def world_ambiguity(lake: str, setup: str, world: int) -> dict[str, float]:
    tr = smspace.load_dataset(f"{setup}-seed{world}-MM", lake).transitions(limit=VIEWS)
    return view_ambiguity(tr.p_t.astype(np.float64), tr.s_t)


def mean_std(values: list[float]) -> str:
    return f"{np.mean(values):.3g} ± {np.std(values):.2g}"


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    for ax, key, label in ((axes[0], "d_topo", "D_topo"), (axes[1], "d_metric", "D_metric (m)")):
        for row in rows:
            ax.scatter(
                row["lookalike_distance"], row[key], color=MODE_COLOURS[row["mode"]],
                marker=LEVEL_MARKERS[row["setup"]], s=60, alpha=0.8, edgecolors="black", linewidths=0.5,
            )  # fmt: skip
        ax.set_xlabel(f"view ambiguity: mean camera distance to each view's {K} look-alikes (m)")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.set_title(f"{label.split(' ')[0]} of each run at its last step")
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=c, marker="o", linestyle="", label=m) for m, c in MODE_COLOURS.items()]
    handles += [
        Line2D([], [], color="gray", marker=LEVEL_MARKERS[s], linestyle="", label=f"level {n}")
        for s, n in LEVEL_NAMES.items()
    ]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    worlds = len({(r["setup"], r["world"]) for r in rows}) // max(1, len({r["setup"] for r in rows}))
    steps = rows[0]["step"]
    fig.suptitle(f"Arm, N_h = 3: view ambiguity against D_topo and D_metric ({worlds} worlds per level, {steps} steps)")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def previews(path: Path) -> None:
    """Eight views of world 0 at each level, from camera positions across the working disc, and
    for the periodic levels the same positions shifted by one period (identical by construction)."""
    from PIL import Image, ImageDraw

    from smspace.datagen.setups import get_setup

    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    xy = np.stack([1.2 * np.cos(angles), 1.2 * np.sin(angles)], 1)
    rows = []
    for setup in LEVEL_NAMES:
        world = get_setup(setup).build(0)
        images = world.render(xy)
        rows.append((LEVEL_NAMES[setup], images))
        period = getattr(world, "period", None)
        if period is not None and period < 5:
            rows.append((f"   same, + {period} m in x", world.render(xy + np.array([period, 0.0]))))
    scale, label_w = 8, 230
    tile = 16 * scale + 4
    canvas = Image.new("RGB", (label_w + 8 * tile, len(rows) * tile + 4), "white")
    draw = ImageDraw.Draw(canvas)
    for r, (label, images) in enumerate(rows):
        draw.text((6, r * tile + tile // 2 - 6), label, fill="black")
        for c, img in enumerate(images):
            big = Image.fromarray(img).resize((16 * scale, 16 * scale), Image.NEAREST)
            canvas.paste(big, (label_w + c * tile, r * tile + 2))
    canvas.save(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/ambiguity"))
    parser.add_argument("--lake", default="data/ambiguity")
    parser.add_argument("--out", type=Path, default=Path("docs/reproduction/ambiguity"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    ambiguity: dict[tuple[str, int], dict[str, float]] = {}
    rows = []
    for run in runs_of(args.runs):
        cfg, last = run.config, run.metrics()[-1]
        key = (cfg.setup, cfg.seed)
        if key not in ambiguity:
            ambiguity[key] = world_ambiguity(args.lake, *key)
        rows.append({"setup": cfg.setup, "world": cfg.seed, "mode": cfg.mode, "step": last["step"],
                     "d_topo": last["d_topo"], "d_metric": last["d_metric"], "loss": last["eval_loss"],
                     **ambiguity[key]})  # fmt: skip
    if len({r["step"] for r in rows}) != 1:
        raise SystemExit(f"the runs are at different steps {sorted({r['step'] for r in rows})}: finish the study first")
    levels = []
    for setup, name in LEVEL_NAMES.items():
        at = [r for r in rows if r["setup"] == setup]
        if not at:
            continue
        worlds = sorted({r["world"] for r in at})
        level = {"setup": setup, "level": name, "worlds": len(worlds)}
        for measure in ("lookalike_distance", "far_lookalikes", "image_geometry_d_topo", "image_geometry_d_metric"):
            values = [ambiguity[(setup, w)][measure] for w in worlds]
            level[measure] = [float(np.mean(values)), float(np.std(values))]
        for mode in MODE_COLOURS:
            for metric in ("d_topo", "d_metric", "loss"):
                values = [r[metric] for r in at if r["mode"] == mode]
                level[f"{mode}_{metric}"] = [float(np.mean(values)), float(np.std(values)), len(values)]
        levels.append(level)
    trend = {}
    for mode in MODE_COLOURS:
        of_mode = [r for r in rows if r["mode"] == mode]
        alike = np.array([r["lookalike_distance"] for r in of_mode])
        for metric in ("d_topo", "d_metric"):
            trend[f"spearman_ambiguity_vs_{mode}_{metric}"] = spearman(alike, np.array([r[metric] for r in of_mode]))
    result = {"k": K, "far": FAR, "views_per_world": VIEWS, "levels": levels, "trend": trend, "runs": rows}
    (args.out / "ambiguity.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        "| level | worlds | look-alike distance (m) | far look-alikes "
        "| MM D_topo | MME D_topo | MM D_metric | MME D_metric |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for lv in levels:
        cells = [f"{lv['lookalike_distance'][0]:.3g} ± {lv['lookalike_distance'][1]:.2g}",
                 f"{lv['far_lookalikes'][0]:.2f} ± {lv['far_lookalikes'][1]:.2f}"]  # fmt: skip
        for metric in ("d_topo", "d_metric"):
            for mode in MODE_COLOURS:
                mean, std, _ = lv[f"{mode}_{metric}"]
                cells.append(f"{mean:.3g} ± {std:.2g}")
        lines.append(f"| {lv['level']} | {lv['worlds']} | " + " | ".join(cells) + " |")
    (args.out / "ambiguity.md").write_text("\n".join(lines) + "\n")
    figure(rows, args.out / "ambiguity.png")
    previews(args.out / "previews.png")
    print(json.dumps({"levels": levels, "trend": trend}, indent=1))


if __name__ == "__main__":
    main()
