#!/usr/bin/env bash
# The study of docs/REPRODUCTION.md, exactly as it was run (about 2 hours on the 2-core machine:
# the grid sweep on one core, arm generation then the arm sweep on the other).
# Usage: bash scripts/reproduce.sh [LAKE] [RUNS]   (defaults data/lake and runs/repro)
set -euo pipefail
cd "$(dirname "$0")/.."
LAKE=${1:-data/lake}
RUNS=${2:-runs/repro}
BIN=.venv/bin

# grid: 3 modes × 10 worlds (seeds 0-9) × 100000 steps, one vectorised ensemble of 30 runs
$BIN/smtrain sweep --setup grid --modes MEM,MM,MME --worlds 10 --seed 0 --steps 100000 --lake "$LAKE" --out "$RUNS/grid" &
# arm: 3 modes × 3 worlds (seeds 0-2), 150000 transitions each, then 100000 steps
$BIN/smgen generate --setup arm --mode all --worlds 3 --seed 0 --lake "$LAKE" --workers 1
$BIN/smtrain sweep --setup arm --modes MEM,MM,MME --worlds 3 --seed 0 --steps 100000 --lake "$LAKE" --out "$RUNS/arm"
wait
$BIN/smtrain report "$RUNS"/grid/* --out docs/reproduction/grid
$BIN/smtrain report "$RUNS"/arm/* --out docs/reproduction/arm
