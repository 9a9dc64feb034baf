#!/usr/bin/env bash
# The studies of docs/REPRODUCTION.md, exactly as they were run on the 2-core machine. Every sweep
# is a study file under studies/ and is resumable: re-running a stage skips finished runs and
# resumes the others from their checkpoints. `smtrain sweep studies/<stage>.toml --dry-run` budgets one.
#
# Usage: bash scripts/reproduce.sh STAGE [LAKE] [RUNS]     (defaults data/lake and runs/repro)
#   grid        3 modes × 10 worlds × 100000 steps, N_h = 3 (about 90 min of one core)
#   grid-full   the grid at the paper's size, 3 modes × 50 worlds × 100000 steps, on this machine's
#               two cores (studies/full/grid-2cores.toml; about 2 h on a quiet machine), then its report
#   arm         3 modes × 3 worlds (seeds 0-2) × 100000 steps (25 min of rendering, 81 min of one core)
#   grid-nh25   the grid study again with N_h = 25 (the same datasets)
#   grid6       the six-motor grid, 3 worlds × 3 modes × 30000 steps, encoder 500-400-300-200
#   arm-more    the arm with 3 more worlds (seeds 3-5) × 100000 steps, MEM and MM only (the
#               MEM-vs-MM order of D_metric is the question; MME adds nothing to it)
#   arm6        the six-motor arm, 3 worlds × 3 modes × 30000 steps, 75000 transitions per dataset
#   reports     every figure and table under docs/reproduction/
#   arm-ambiguity  how alike the views of each arm room are, beside the arm runs' metrics (1 min)
#   ambiguity   beyond the paper: the arm in rooms whose views repeat (examples/ambiguous-room, a
#               plugin), 4 levels x 4 worlds x MM, MME x 40000 steps, then its analysis (~80 min)
#   precision   the grid in fp32 beside bf16, 10 worlds x 3 modes x 100000 steps each, then the
#               comparison (~70 min on both cores of this machine)
#   new         grid-nh25, grid6, arm-more, arm6, then reports (both cores for each sweep)
#   rest        grid6, arm-more, arm6, then reports (what was left of `new` after a restart)
#   full        every study at the paper's size (50 worlds × 100000 steps) on a Ray cluster, with
#               the lake and the runs on object storage (README, "Scaling out"); not run here:
#               RAY_ADDRESS=ray://head:10001 WORKERS=256 bash scripts/reproduce.sh full s3://b/lake s3://b/runs
set -euo pipefail
cd "$(dirname "$0")/.."
STAGE=${1:?give a stage: grid, grid-full, arm, grid-nh25, grid6, arm-more, arm6, reports, arm-ambiguity, ambiguity, precision, new, rest, full}
LAKE=${2:-data/lake}
RUNS=${3:-runs/repro}
BIN=.venv/bin
CORES=$(nproc)
# Each study is a file under studies/ (what it computes); this script only says where it runs.
study() { "$BIN/smtrain" sweep "studies/$1.toml" --lake "$LAKE" --out "$RUNS/$1" --workers "$CORES" --gen-workers "$CORES"; }

grid() { study grid; }
grid_full() {
  "$BIN/smtrain" sweep studies/full/grid-2cores.toml --lake "$LAKE" --out "$RUNS/grid-full"
  "$BIN/smtrain" report "$RUNS/grid-full" --out docs/reproduction/grid-full
}
arm() { study arm; }
grid_nh25() { study grid-nh25; }
grid6() { study grid6; }
arm_more() { study arm-more; }
arm6() { study arm6; }
full() {
  : "${RAY_ADDRESS:?full runs on a Ray cluster: set RAY_ADDRESS}"
  for name in grid grid6 arm arm6 grid-nh25; do
    "$BIN/smtrain" sweep "studies/full/$name.toml" --lake "$LAKE" --out "$RUNS/$name" --workers "${WORKERS:-64}"
  done
  echo "reports: $BIN/smtrain report $RUNS/<study> --out docs/reproduction/<study>"
}
arm_ambiguity() {
  "$BIN/python" scripts/arm_ambiguity.py --seeds 0-5 --lake data/ambiguity-lake \
    --runs docs/reproduction/arm/runs.csv --runs docs/reproduction/arm-more/runs.csv > docs/reproduction/arm-ambiguity.json
}
ambiguity() {
  "$BIN/smtrain" sweep examples/ambiguous-room/study.toml --lake data/ambiguity --out "$RUNS/ambiguity" --workers "$CORES"
  "$BIN/python" examples/ambiguous-room/analyse.py --runs "$RUNS/ambiguity" --lake data/ambiguity --out docs/reproduction/ambiguity
}
precision() {
  study grid-precision
  for p in fp32 bf16; do "$BIN/smtrain" report "$RUNS/grid-precision/precision=$p" --out "docs/reproduction/grid-precision/$p"; done
  "$BIN/python" scripts/compare_studies.py docs/reproduction/grid-precision/fp32/runs.csv \
    docs/reproduction/grid-precision/bf16/runs.csv > docs/reproduction/grid-precision/comparison.json
}
reports() {
  for study in grid arm grid-nh25 grid6 arm-more arm6; do
    if compgen -G "$RUNS/$study/*/metrics.parquet" >/dev/null; then
      "$BIN/smtrain" report "$RUNS/$study" --out "docs/reproduction/$study"
    fi
  done
}

case "$STAGE" in
  grid) grid ;;
  grid-full) grid_full ;;
  arm) arm ;;
  grid-nh25) grid_nh25 ;;
  grid6) grid6 ;;
  arm-more) arm_more ;;
  arm6) arm6 ;;
  reports) reports ;;
  full) full ;;
  arm-ambiguity) arm_ambiguity ;;
  ambiguity) ambiguity ;;
  precision) precision ;;
  new) grid_nh25; grid6; arm_more; arm6; reports ;;
  rest) grid6; arm_more; arm6; reports ;;
  *) echo "unknown stage $STAGE" >&2; exit 2 ;;
esac
