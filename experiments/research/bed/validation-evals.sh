#!/usr/bin/env bash
# experiments/bed/README.md rule 18 (twentieth session): a finished run scored on the scene's
# validation views (`eval.novel_views = "validation"`; scripts/testbed/validation_views.py adds
# them) instead of its test view. The run folder is copied (its stages as they are, no evaluation)
# to DEST, so the run's own evaluation of the test view stays, then evaluated there; with NERF_T=1
# its NeRF-T (NeuroFluid's images) is scored on the same views. Extra arguments go to both commands (e.g. `--set refit.enabled=true`
# for a run whose renderer is the refit's: the evaluation must score the renderer the run used).
# SCENE is a bed scene's name (its config experiments/bed/SCENE.toml) or a config's path (a
# built-in scene's quick config, with `--set scene.generate.validation_views=true`: rule 19).
# Usage: experiments/research/bed/validation-evals.sh SCENE RUN DEST [--set key=value ...]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 run=$2 dest=$3
shift 3
config=experiments/bed/$scene.toml
if [[ $scene == *.toml ]]; then config=$scene; fi
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
mkdir -p "$dest"
for file in config.resolved.toml config.history metrics.jsonl metrics.csv; do
  if [[ -f $run/$file && ! -f $dest/$file ]]; then cp "$run/$file" "$dest/"; fi
done
for stage in warmup joint refit nerf-t; do
  if [[ -d $run/$stage && ! -d $dest/$stage ]]; then cp -r "$run/$stage" "$dest/"; fi
done
set_val=(--set out_dir="$dest" --set eval.novel_views="validation" --set eval.render_truth=true "$@")
if [[ ${NERF_T:-0} == 1 && -d $dest/nerf-t ]]; then
  "$bin" baseline nerf-t "$config" "${set_val[@]}" --set nerf.t_images="neurofluid" \
    > "$dest/nerf-t-val.log" 2>&1
fi
"$bin" eval "$config" "${set_val[@]}" > "$dest/eval-val.log" 2>&1
