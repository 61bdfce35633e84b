#!/usr/bin/env bash
# experiments/bed/README.md rule 17 (nineteenth session): the refit (positions relative) with and
# without `refit.replay_rays = 256`, on copies of rule 15's `plain` run folders (view_3 held out
# of every stage; their warm-up and joint stage are reused as they are, only the refit and the
# evaluation run).
# Usage: experiments/research/bed/refit-replay-runs.sh [FROM=runs/r15] [OUT=runs/r17] [JOBS=2]
set -euo pipefail
cd "$(dirname "$0")/../../.."
from=${1:-runs/r15}
out=${2:-runs/r17}
jobs=${3:-2}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
declare -A config=(
  [water-dam-z]=experiments/bed/water-dam-z.toml
  [honey-drop-z]=experiments/bed/honey-drop-z.toml
  [watercube]=experiments/quick-watercube.toml
)
for scene in water-dam-z honey-drop-z watercube; do
  for rays in 0 256; do
    dir=$out/$scene-refit-$rays
    if [[ ! -d $dir ]]; then
      mkdir -p "$dir"
      cp -r "$from/$scene-plain/warmup" "$from/$scene-plain/joint" "$dir/"
    fi
    echo "$bin run ${config[$scene]} --set out_dir=\"$dir\" --set warmup.held_out=\"view_3\" --set eval.render_truth=true --set refit.enabled=true --set refit.replay_rays=$rays"
  done
done | xargs -P "$jobs" -I{} bash -c '{} > /dev/null 2>&1 || echo "failed: {}"'
