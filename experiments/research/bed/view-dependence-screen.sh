#!/usr/bin/env bash
# The screen of experiments/bed/README.md rule 13 (eighteenth session): each scene's shipped
# config warmed up at seed 10 with one warm-up view held out (`warmup.held_out`), for the paper's
# view dependence (A) and the raw direction only (B); rule 14: one frequency each (C). The
# held-out view's PSNR at the last warm-up step is the rules' measure
# (python3 scripts/analysis/held-out-table.py runs/r13).
# Usage: [SCENES="…"] [VARIANTS="A B"] experiments/research/bed/view-dependence-screen.sh [OUT=runs/r13] [JOBS=2]
# Rule 13: the defaults. Rule 14: SCENES="water-dam-z honey-drop-z watercube water-torus-tilted-z"
#   VARIANTS="A C" (A's folds already run are skipped).
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=${1:-runs/r13}
jobs=${2:-2}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
declare -A config=(
  [water-dam-z]=experiments/bed/water-dam-z.toml
  [honey-drop-z]=experiments/bed/honey-drop-z.toml
  [watercube]=experiments/quick-watercube.toml
  [water-torus-tilted-z]=experiments/bed/water-torus-tilted-z.toml
)
declare -A variant=(
  [A]=""
  [B]="--set physnerf.frequencies.d=0 --set physnerf.encoding.dc=false"
  [C]="--set physnerf.frequencies.d=1 --set physnerf.frequencies.dc=1"
)
scenes=${SCENES:-water-dam-z honey-drop-z watercube}
variants=${VARIANTS:-A B}
for scene in $scenes; do
  for v in $variants; do
    for view in view_2 view_3 view_4; do
      dir="$out/$scene-$v-$view"
      grep -qs '"stage":"warmup-preview","step":800' "$dir/metrics.jsonl" && continue
      echo "$bin warmup ${config[$scene]} --set out_dir=\"$dir\" --set warmup.held_out=\"$view\" ${variant[$v]}"
    done
  done
done | xargs -P "$jobs" -I{} bash -c '{} > /dev/null 2>&1 || echo "failed: {}"'
