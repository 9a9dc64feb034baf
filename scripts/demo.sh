#!/usr/bin/env bash
# The main job end to end on small defaults: generate one grid world in its three modes, validate
# the datasets, train a short run on each and print the final loss, D_topo and D_metric.
# Usage: bash scripts/demo.sh [LAKE] [RUNS]   (defaults data/lake and runs)
set -euo pipefail
cd "$(dirname "$0")/.."
LAKE=${1:-data/lake}
RUNS=${2:-runs}
BIN=.venv/bin

$BIN/smgen generate --setup grid --mode all --transitions 30000 --seed 0 --lake "$LAKE"
$BIN/smgen validate --lake "$LAKE" grid-seed0-MEM grid-seed0-MM grid-seed0-MME
for mode in MEM MM MME; do
  $BIN/smtrain fit "grid-seed0-$mode" --lake "$LAKE" --steps 3000 --out "$RUNS/demo-grid-seed0-$mode" --overwrite
done
$BIN/smtrain ls --runs "$RUNS"
echo "Expected shape (SPEC 4): loss MEM high, MM/MME low; D_topo MEM high; D_metric MEM > MM > MME."
