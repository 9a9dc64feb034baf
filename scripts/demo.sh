#!/usr/bin/env bash
# The main job end to end on small defaults: generate a grid world (three modes) and validate it.
# Usage: bash scripts/demo.sh [LAKE]   (default data/lake)
set -euo pipefail
cd "$(dirname "$0")/.."
LAKE=${1:-data/lake}
BIN=.venv/bin

$BIN/smgen generate --setup grid --mode all --transitions 30000 --seed 0 --lake "$LAKE"
$BIN/smgen validate --lake "$LAKE" grid-seed0-MEM grid-seed0-MM grid-seed0-MME
$BIN/smgen ls --lake "$LAKE"
