#!/usr/bin/env bash
# The studies of docs/REPRODUCTION.md, exactly as they were run on the 2-core machine. Every sweep
# is resumable: re-running a stage skips finished runs and resumes the others from their checkpoints.
#
# Usage: bash scripts/reproduce.sh STAGE [LAKE] [RUNS]     (defaults data/lake and runs/repro)
#   grid        3 modes × 10 worlds × 100000 steps, N_h = 3 (about 90 min of one core)
#   arm         3 modes × 3 worlds (seeds 0-2) × 100000 steps (25 min of rendering, 81 min of one core)
#   grid-nh25   the grid study again with N_h = 25 (the same datasets)
#   grid6       the six-motor grid, 3 worlds × 3 modes × 30000 steps, encoder 500-400-300-200
#   arm-more    the arm with 3 more worlds (seeds 3-5) × 100000 steps, MEM and MM only (the
#               MEM-vs-MM order of D_metric is the question; MME adds nothing to it)
#   arm6        the six-motor arm, 3 worlds × 3 modes × 30000 steps, 75000 transitions per dataset
#   reports     every figure and table under docs/reproduction/
#   arm-ambiguity  how alike the views of each arm room are, beside the arm runs' metrics (1 min)
#   new         grid-nh25, grid6, arm-more, arm6, then reports (both cores for each sweep)
#   rest        grid6, arm-more, arm6, then reports (what was left of `new` after a restart)
#   full        every study at the paper's size (50 worlds × 100000 steps) on a Ray cluster, with
#               the lake and the runs on object storage (README, "Scaling out"); not run here:
#               RAY_ADDRESS=ray://head:10001 WORKERS=256 bash scripts/reproduce.sh full s3://b/lake s3://b/runs
set -euo pipefail
cd "$(dirname "$0")/.."
STAGE=${1:?give a stage: grid, arm, grid-nh25, grid6, arm-more, arm6, reports, arm-ambiguity, new, rest, full}
LAKE=${2:-data/lake}
RUNS=${3:-runs/repro}
BIN=.venv/bin
CORES=$(nproc)
SWEEP=("$BIN/smtrain" sweep --lake "$LAKE" --workers "$CORES" --gen-workers "$CORES")

grid() { "${SWEEP[@]}" --setup grid --worlds 10 --seed 0 --steps 100000 --out "$RUNS/grid"; }
arm() {
  "$BIN/smgen" generate --setup arm --mode all --worlds 3 --seed 0 --lake "$LAKE" --workers "$CORES"
  "${SWEEP[@]}" --setup arm --worlds 3 --seed 0 --steps 100000 --out "$RUNS/arm"
}
grid_nh25() { "${SWEEP[@]}" --setup grid --worlds 10 --seed 0 --steps 100000 --nh 25 --out "$RUNS/grid-nh25"; }
grid6() { "${SWEEP[@]}" --setup grid6 --worlds 3 --seed 0 --steps 30000 --out "$RUNS/grid6"; }
arm_more() { "${SWEEP[@]}" --modes MEM,MM --setup arm --worlds 3 --seed 3 --steps 100000 --out "$RUNS/arm-more"; }
# 75000 transitions per arm6 dataset, a quarter of the setup's 300000, and an evaluation every 3000
# steps: on two cores, rendering 2.7 M images takes 100 min and each evaluation over the 15625
# regular states 5 s per run (30000 steps of batch 100 still visit each transition 40 times).
arm6() {
  "${SWEEP[@]}" --setup arm6 --worlds 3 --seed 0 --steps 30000 --transitions 75000 --eval-every 3000 \
    --out "$RUNS/arm6"
}
full() {
  : "${RAY_ADDRESS:?full runs on a Ray cluster: set RAY_ADDRESS}"
  local ray=(--executor ray --workers "${WORKERS:-64}")
  for setup in grid grid6 arm arm6; do
    "$BIN/smgen" generate --setup "$setup" --mode all --worlds 50 --seed 0 --lake "$LAKE" "${ray[@]}"
    "$BIN/smtrain" sweep --setup "$setup" --worlds 50 --steps 100000 --lake "$LAKE" --out "$RUNS/$setup" "${ray[@]}"
  done
  "$BIN/smtrain" sweep --setup grid --worlds 50 --steps 100000 --nh 25 --lake "$LAKE" --out "$RUNS/grid-nh25" "${ray[@]}"
  echo "reports: $BIN/smtrain report $RUNS/<study>/<run>... --out docs/reproduction/<study> (run folders: smtrain ls --runs $RUNS/<study>)"
}
arm_ambiguity() {
  "$BIN/python" scripts/arm_ambiguity.py --seeds 0-5 --lake data/ambiguity-lake \
    --runs docs/reproduction/arm/runs.csv --runs docs/reproduction/arm-more/runs.csv > docs/reproduction/arm-ambiguity.json
}
reports() {
  for study in grid arm grid-nh25 grid6 arm-more arm6; do
    if compgen -G "$RUNS/$study/*/metrics.parquet" >/dev/null; then
      "$BIN/smtrain" report "$RUNS/$study"/* --out "docs/reproduction/$study"
    fi
  done
}

case "$STAGE" in
  grid) grid ;;
  arm) arm ;;
  grid-nh25) grid_nh25 ;;
  grid6) grid6 ;;
  arm-more) arm_more ;;
  arm6) arm6 ;;
  reports) reports ;;
  full) full ;;
  arm-ambiguity) arm_ambiguity ;;
  new) grid_nh25; grid6; arm_more; arm6; reports ;;
  rest) grid6; arm_more; arm6; reports ;;
  *) echo "unknown stage $STAGE" >&2; exit 2 ;;
esac
