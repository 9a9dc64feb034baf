#!/usr/bin/env bash
# The main job end to end on small defaults: generate one grid world in its three modes, validate
# the datasets, train a short run on each, print the final loss, D_topo and D_metric, draw the
# paper's figures and write rerun recordings of the data and of what was learned.
# Usage: bash scripts/demo.sh [LAKE] [RUNS]   (defaults data/demo-lake and runs)
# The demo has a lake of its own: its datasets are shorter (30000 transitions) than the studies'
# (scripts/reproduce.sh, 150000) under the same ids, and one lake refuses to hold both.
set -euo pipefail
cd "$(dirname "$0")/.."
LAKE=${1:-data/demo-lake}
RUNS=${2:-runs}
BIN=.venv/bin

$BIN/smgen generate --setup grid --mode all --transitions 30000 --seed 0 --lake "$LAKE"
$BIN/smgen validate --lake "$LAKE" grid-seed0-MEM grid-seed0-MM grid-seed0-MME
for mode in MEM MM MME; do
  $BIN/smtrain fit "grid-seed0-$mode" --lake "$LAKE" --steps 3000 --out "$RUNS/demo-grid-seed0-$mode" --overwrite
done
$BIN/smtrain ls --runs "$RUNS"
$BIN/smtrain report "$RUNS"/demo-grid-seed0-MEM "$RUNS"/demo-grid-seed0-MM "$RUNS"/demo-grid-seed0-MME --out "$RUNS/demo-report"
$BIN/smgen view grid-seed0-MME --lake "$LAKE" --save "$RUNS/demo-dataset.rrd"
$BIN/smtrain view "$RUNS/demo-grid-seed0-MME" --save "$RUNS/demo-run.rrd"
cat "$RUNS/demo-report/final.md"
echo "Figures: $RUNS/demo-report/*.png; recordings: rerun $RUNS/demo-dataset.rrd $RUNS/demo-run.rrd"
echo "Expected shape (docs/MODEL.md §4): loss MEM high, MM/MME low; D_topo MEM high; D_metric MEM > MM > MME."
