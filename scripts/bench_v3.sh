#!/usr/bin/env bash
# Measure spatial@3's tasks one after another, resumably, and keep each finished result where a
# lost machine cannot take it: after every task, each entry's bench.json, scores.json and evidence/
# are copied into docs/bench/<task>/results/ (tracked; the run folders with their checkpoints stay
# in WORK, which is only needed to resume) and that task's leaderboard is rebuilt.
#   nohup setsid bash scripts/bench_v3.sh WORK [TASK ...] > WORK.out 2>&1 &
# WORK: where the lake and the runs live (outside the checkout). The same command continues: from
# WORK's checkpoints, and, where WORK was lost with a machine, an entry whose result is already
# published (its scores.json in PUBLISH) is not trained again; only the entries still missing run.
# PUBLISH (default: this checkout's docs/bench): where results are copied, every 10 minutes while a
# task runs (an entry's folder once its scores.json exists) and when it ends.
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:?usage: bench_v3.sh WORK [TASK ...]}
shift
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(grid6-w10 floor1-w6 floor2-w6 floor24-w6 arm-w6)
suite=${SUITE:-spatial@3}  # SUITE, ENTRIES: another suite or entries (how the script is tried on tiny@2)
read -r -a entries <<< "${ENTRIES:-sensorimotor motor-autoencoder contrastive random-encoder isomap beta-vae latent-forward slow-features displacement}"
label="${suite%@*}-v${suite#*@}"
publish=${PUBLISH:-docs/bench}
mkdir -p "$work"

mirror() {  # copy each entry's result of task $1 that has scores into $publish/$1/results
  local result entry to
  for result in "$work"/runs/$label/*/"$1"; do
    [ -f "$result/scores.json" ] || continue
    entry=$(basename "$(dirname "$result")")
    to="$publish/$1/results/$label/$entry/$1"
    mkdir -p "$to"
    cp "$result/bench.json" "$result/scores.json" "$to/"
    rm -rf "$to/evidence"
    [ ! -d "$result/evidence" ] || cp -r "$result/evidence" "$to/"
  done
}

missing() {  # the entries of task $1 whose result is not published yet
  local entry
  for entry in "${entries[@]}"; do
    [ -f "$publish/$1/results/$label/$entry/$1/scores.json" ] || echo "$entry"
  done
}

for task in "${tasks[@]}"; do
  mapfile -t todo < <(missing "$task")
  echo "$(date -u +%FT%TZ) start $task: ${todo[*]:-every entry published}" >> "$work/chain.log"
  if [ ${#todo[@]} -eq 0 ]; then
    : > "$work/log-$task"
    true &
  else
    .venv/bin/smtrain bench "$suite" "${todo[@]}" --task "$task" --lake "$work/lake" --out "$work/runs" \
      --workers 2 > "$work/log-$task" 2>&1 &
  fi
  pid=$!
  while kill -0 "$pid" 2>/dev/null; do
    for _ in 1 2 3 4 5 6 7 8 9 10; do kill -0 "$pid" 2>/dev/null || break; sleep 60; done
    mirror "$task"
  done
  rc=0
  wait "$pid" || rc=$?
  echo "$(date -u +%FT%TZ) end $task rc=$rc" >> "$work/chain.log"
  mirror "$task"
  [ "$rc" -eq 0 ] && .venv/bin/smtrain leaderboard "$publish/$task/results" --out "$publish/$task" --html \
    >> "$work/chain.log" 2>&1 || true
done
