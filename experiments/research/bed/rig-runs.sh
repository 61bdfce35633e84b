#!/usr/bin/env bash
# Issue 71, item 5: the joint stage on 1, 2 or 4 views of the dynamics (the bed renders its four
# warm-up views at every frame): RIG 2 adds the warm-up view whose camera is farthest from the
# training view's (the opposite one on a ring), RIG 4 adds the other three (`joint.extra_views`).
# Runs the bed config as it ships at SEED on a copy of A's warm-up (A_RUN, default
# runs/bed71/<scene>-s<seed>-A of screen.sh), evaluated like a screen (no renders, no refit).
# Reported beside the single-view table; chooses nothing.
# Usage: experiments/research/bed/rig-runs.sh SCENE SEED RIG [A_RUN] [OUT=runs/rig71]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 seed=$2 rig=$3
a=${4:-runs/bed71/$scene-s$seed-A} out=${5:-runs/rig71}
bin=${NEUROFLUID_TRAIN:-target/release/neurofluid-train}
views=$(python3 experiments/research/bed/rig-views.py "data/bed/$scene" "$rig")
b=$out/$scene-s$seed-rig$rig
mkdir -p "$b"
[[ -f $a/eval/report.json ]] || { echo "$a: run A first (screen.sh)" >&2; exit 2; }
[[ -d $b/warmup ]] || cp -r "$a/warmup" "$b/"
if [[ ! -f $b/eval/report.json ]]; then
  "$bin" run "experiments/bed/$scene.toml" --set seed="$seed" --set refit.enabled=false \
    --set eval.render=false --set out_dir="$b" --set "joint.extra_views=$views" >> "$b.log" 2>&1
fi
