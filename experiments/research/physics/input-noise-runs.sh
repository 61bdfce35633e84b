#!/usr/bin/env bash
# Issue 71, item 7: the screen of noise on the training rollout's inputs (`joint.input_noise`) on a
# time split of the built-in choosing scenes (docs/notebook/2026-12-05-steady-rollouts.md): the
# scene generated with 30 training frames and 50 test frames, so the report's prediction window is
# t = 30-49, frames of the real task's training window that this run never trains on. U0 (the
# one-config candidate: the three scalars fitted, DLF held) and N0 (U0 with σ = 0.1 m/s) share
# U0's warm-up; evaluated without renders.
#   bash experiments/research/physics/input-noise-runs.sh VARIANT SCENE SEED   (VARIANT: U0 or N0)
set -euo pipefail
cd "$(dirname "$0")/../../.."
variant=$1 scene=$2 seed=$3
bin=${NF_BIN:-target/release/neurofluid-train}
out=runs/noise/$variant-$scene-s$seed
u0=(--set joint.physics.hold_dlf_epochs=6)
case $variant in
  U0) sets=("${u0[@]}") ;;
  N0) sets=("${u0[@]}" --set joint.input_noise=0.1) ;;
  *) echo "VARIANT: U0 or N0, not $variant" >&2; exit 2 ;;
esac
[[ -f $out/eval/report.json ]] && exit 0
warm=runs/noise/U0-$scene-s$seed/warmup
if [[ $variant != U0 && ! -d $out/warmup ]]; then
  [[ -f $warm/../eval/report.json ]] || { echo "run U0 $scene $seed first" >&2; exit 2; }
  mkdir -p "$out" && cp -r "$warm" "$out/"
fi
mkdir -p "$(dirname "$out")"
"$bin" run experiments/research/physics/one-config.toml --set "scene.builtin=\"$scene\"" \
  --set "scene.dir=\"data/${scene}_split30\"" --set scene.generate.train_frames=30 \
  --set scene.generate.test_frames=50 \
  --set "seed=$seed" --set "name=\"noise-$variant-$scene-s$seed\"" --set "out_dir=\"$out\"" \
  --set eval.render=false --set eval.write_ply=false "${sets[@]}" >> "$out.log" 2>&1
