"""smspace side by side with what a researcher would otherwise use, on one core of this machine: the
same network (N_h 3, the paper's grid layers), batch (100), schedule (linear 1e-3 -> 1e-5 over 80 %
of the steps) and steps, timed in one run and printed as ratios.

- the authors' pipeline: their TF1 graph through tf.compat.v1, one run at a time, fed numpy batches
  drawn with replacement (tf1_authors.py);
- JAX by hand: vmap + jit + optax Adam, one run and R runs at once (jax_ensemble.py);
- smspace as a user runs it: `smtrain fit` (one run) and `smtrain sweep` (R runs stacked in one
  ensemble), eager and --compile on; its time per step is what its runs record (elapsed_s: the
  training loop with its data path, without evaluations and writes).

Every contender runs in its own process pinned to one core (taskset) with one thread, one after
another; each figure is the steady ms per run-step after the first `--warmup` steps (compilation,
tracing, caches), and the warm-up's seconds are given beside it. The contenders' own libraries live
in a separate environment (requirements.txt) named by --peers-python.

Prints one JSON object; say what else ran beside it.
Usage: python benchmarks/peers/run.py [--runs 30] [--steps 3000] [--warmup 1000]
       [--peers-python .venv-peers/bin/python] [--core 0]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BIN = Path(sys.executable).parent
ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def pinned(core: int) -> list[str]:
    return ["taskset", "-c", str(core)] if shutil.which("taskset") else []


def export(dataset: Path, to: Path) -> None:
    """The dataset's transitions, normalised as smspace trains on them, for the other contenders."""
    from smspace.lake.dataset import Dataset
    from smspace.lake.normalise import normalisers

    ds = Dataset(dataset)
    t = ds.read_all()
    m_norm, s_norm = normalisers(ds.manifest)
    np.savez(to, m_t=m_norm(t.m_t), s_t=s_norm(t.s_t), m_t1=m_norm(t.m_t1), s_t1=s_norm(t.s_t1))


def peer(python: str, script: str, args: list, core: int) -> dict:
    cmd = [*pinned(core), python, str(HERE / script), *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=os.environ | ONE_THREAD)
    if done.returncode != 0:
        raise SystemExit(f"{script} failed: {(done.stderr.strip().splitlines() or ['no output'])[-1]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def smspace(command: list, steps: int, warmup: int, core: int, runs: int) -> dict:
    """One smspace command, into a fresh folder; its ms per run-step from the elapsed time its runs record."""
    out = Path(tempfile.mkdtemp(dir=command[command.index("--lake") + 1].parent)) / "runs"
    command = [*command, "--out", out]
    started = time.perf_counter()
    done = subprocess.run(
        [*pinned(core), *map(str, command)], capture_output=True, text=True, env=os.environ | ONE_THREAD
    )
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{command[:2]} failed: {(done.stderr.strip().splitlines() or ['no output'])[-1]}")
    from smspace.train.run_dir import RunView

    folder = out if (out / "config.json").exists() else next(p.parent for p in sorted(out.glob("*/config.json")))
    rows = {row["step"]: row["elapsed_s"] for row in RunView.open(folder).metrics()}
    # a member's elapsed_s is the ensemble's loop time divided by its runs: per run-step already
    return {
        "runs": runs,
        "ms_per_run_step": round((rows[steps] - rows[warmup]) / (steps - warmup) * 1e3, 4),
        "warmup_s": round(rows[warmup] * runs, 2),
        "command_wall_s": round(wall, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=30, help="runs of the ensembles (a multiple of 3: worlds x modes)")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--warmup", type=int, default=1000)
    ap.add_argument("--peers-python", default=str(HERE.parent.parent / ".venv-peers" / "bin" / "python"))
    ap.add_argument("--core", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=2, help="each contender this many times, in turn; the best is kept")
    args = ap.parse_args()
    if args.runs % 3 or args.steps <= args.warmup or args.warmup < 1:
        raise SystemExit("--runs must be a multiple of 3 and --steps above --warmup (at least 1)")
    if not Path(args.peers_python).exists():
        raise SystemExit(f"no peers' python at {args.peers_python}: see benchmarks/peers/requirements.txt")
    worlds, steps, warmup, core = args.runs // 3, args.steps, args.warmup, args.core
    schedule = ["--steps", steps, "--eval-every", warmup, "--threads", 1]
    with tempfile.TemporaryDirectory() as tmp:
        lake, data = Path(tmp) / "lake", Path(tmp) / "grid-seed0-MM.npz"
        generate = [BIN / "smgen", "generate", "--setup", "grid", "--mode", "all", "--worlds", worlds, "--lake", lake]
        subprocess.run([str(x) for x in generate], check=True, capture_output=True)
        export(lake / "grid-seed0-MM", data)
        peer_args = [data, "--steps", steps, "--warmup", warmup]
        fit = [BIN / "smtrain", "fit", "grid-seed0-MM", "--lake", lake, *schedule]
        sweep = [BIN / "smtrain", "sweep", "--setup", "grid", "--modes", "all", "--worlds", worlds, "--lake", lake,
                 "--workers", 1, *schedule]  # fmt: skip
        contenders = {
            "authors' TF1 graph (tf.compat.v1), one run at a time":
                lambda: peer(args.peers_python, "tf1_authors.py", peer_args, core),
            "JAX vmap + jit + optax Adam, one run":
                lambda: peer(args.peers_python, "jax_ensemble.py", [*peer_args, "--runs", 1], core),
            f"JAX vmap + jit + optax Adam, {args.runs} runs at once":
                lambda: peer(args.peers_python, "jax_ensemble.py", [*peer_args, "--runs", args.runs], core),
            "smspace: smtrain fit, one run, eager":
                lambda: smspace(fit, steps, warmup, core, 1),
            "smspace: smtrain fit, one run, --compile on":
                lambda: smspace([*fit, "--compile", "on"], steps, warmup, core, 1),
            f"smspace: smtrain sweep, {args.runs} runs stacked, eager":
                lambda: smspace(sweep, steps, warmup, core, args.runs),
            f"smspace: smtrain sweep, {args.runs} runs stacked, --compile on":
                lambda: smspace([*sweep, "--compile", "on"], steps, warmup, core, args.runs),
        }  # fmt: skip
        rounds: dict[str, list[dict]] = {name: [] for name in contenders}
        for _ in range(args.rounds):  # in turn, so that a slower minute of a shared machine hits them all
            for name, run in contenders.items():
                rounds[name].append(run())
    timed = [min(got, key=lambda t: t["ms_per_run_step"]) | {"contender": name} for name, got in rounds.items()]
    best = min(t["ms_per_run_step"] for t in timed if t["contender"].startswith("smspace"))
    for t in timed:
        t["x_best_smspace"] = round(t["ms_per_run_step"] / best, 2)
    print(
        json.dumps(
            {"benchmark": "peers", "steps": steps, "warmup": warmup, "core": core, "rounds": args.rounds,
             "cpu": cpu_model(), "contenders": timed}
        )
    )  # fmt: skip


def cpu_model() -> str:
    from smspace.common.provenance import cpu

    return cpu()["cpu"]


if __name__ == "__main__":
    main()
