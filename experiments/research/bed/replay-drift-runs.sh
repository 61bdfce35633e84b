#!/usr/bin/env bash
# experiments/bed/README.md rule 15 (eighteenth session): the joint stage with view_3 held out
# of every stage, as the configs ship and with the warm-up's other views replayed, from rule
# 13's warm-up (view-dependence-screen.sh's <scene>-A-view_3, copied into each run folder).
# Rule 16 (nineteenth session) adds the variant `renders` (the warm-up renderer's renders from
# all round the fluid replayed); VARIANTS picks the variants run (default: plain replay), and a
# run folder without a warm-up takes the `plain` run's of WARMUPS (default: OUT) when it has one.
# Usage: [VARIANTS="renders"] [WARMUPS=runs/r15] experiments/research/bed/replay-drift-runs.sh [OUT=runs/r15] [JOBS=2]
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=${1:-runs/r15}
jobs=${2:-2}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
declare -A config=(
  [water-dam-z]=experiments/bed/water-dam-z.toml
  [honey-drop-z]=experiments/bed/honey-drop-z.toml
  [watercube]=experiments/quick-watercube.toml
)
declare -A variant=(
  [plain]=""
  [replay]="--set joint.replay_rays=256"
  [renders]="--set joint.replay_rays=256 --set joint.replay_of=\"renders\""
)
warmups=${WARMUPS:-$out}
for scene in water-dam-z honey-drop-z watercube; do
  for v in ${VARIANTS:-plain replay}; do
    if [[ ! -d $out/$scene-$v/warmup && -d $warmups/$scene-plain/warmup ]]; then
      mkdir -p "$out/$scene-$v"
      cp -r "$warmups/$scene-plain/warmup" "$out/$scene-$v/"
    fi
    echo "$bin run ${config[$scene]} --set out_dir=\"$out/$scene-$v\" --set warmup.held_out=\"view_3\" --set eval.render_truth=true ${variant[$v]}"
  done
done | xargs -P "$jobs" -I{} bash -c '{} > /dev/null 2>&1 || echo "failed: {}"'
