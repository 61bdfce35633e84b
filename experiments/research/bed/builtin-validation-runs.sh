#!/usr/bin/env bash
# experiments/bed/README.md rule 19 (twenty-first and twenty-second sessions): on a built-in
# scene's quick config at one seed, A (the config as it ships, its scene with validation views)
# and C (the refit with the warm-up renderer's renders replayed, on a copy of A's warm-up and
# joint stages), each scored on the validation views by validation-evals.sh; with NERF_T=1,
# NeRF-T on NeuroFluid's images into A's folder too (item 4, reported). A run already evaluated
# or scored is not run again; a stopped one resumes from its checkpoints. The runs list for
# scripts/analysis/validation-table.py is experiments/research/bed/validation-builtin-runs.txt.
# Usage: [NERF_T=1] experiments/research/bed/builtin-validation-runs.sh SCENE SEED [OUT=runs/r19]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 seed=$2 out=${3:-runs/r19}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
config=experiments/quick-$scene.toml
a=$out/b-$scene-s$seed-A c=$out/b-$scene-s$seed-C
scored=(--set seed="$seed" --set scene.generate.validation_views=true)
common=("${scored[@]}" --set eval.render_truth=true)
refit=(--set refit.enabled=true --set refit.replay_rays=256)
mkdir -p "$a" "$c"
if [[ ! -f $a/eval/report.json ]]; then
  "$bin" run "$config" "${common[@]}" --set out_dir="$a" >> "$a.log" 2>&1
fi
if [[ ! -d $c/joint ]]; then
  cp -r "$a/warmup" "$a/joint" "$c/"
fi
if [[ ! -f $c/eval/report.json ]]; then
  "$bin" run "$config" "${common[@]}" "${refit[@]}" --set out_dir="$c" >> "$c.log" 2>&1
fi
score() { # run candidate [--set ...]: the run scored on the validation views, once
  local dest=$out/val/b-$scene-s$seed-$2 run=$1
  shift 2
  if [[ ! -f $dest/eval/report.json ]]; then
    experiments/research/bed/validation-evals.sh "$config" "$run" "$dest" "${scored[@]}" "$@"
  fi
}
score "$a" A
score "$c" C "${refit[@]}"
if [[ ${NERF_T:-0} == 1 && ! -f $a/nerf-t/scores.json ]]; then
  "$bin" baseline nerf-t "$config" "${common[@]}" --set out_dir="$a" \
    --set nerf.t_images=neurofluid >> "$a.nerft.log" 2>&1
fi
