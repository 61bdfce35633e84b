#!/usr/bin/env bash
# Issue 71, probe P7 (docs/notebook/2026-12-06-image-landscape.md): the training view's image loss
# on scalar-scan.sh's grid (the gravity scale × the bodies'-frame dissipation), with nothing
# trained: A's warm-up (the bed config as it ships, at SEED), then at each point one joint epoch
# on a copy of it with every learning rate 0, no particle terms, one transition a window and
# uniform rays (the same pixels at every point), evaluated once at the end (the diagnostics:
# `rollout_psnr` beside `psnr_true`, the renderer on the rollout and on the truth at the same
# pixels). EXTRA_VIEW adds a second view of the dynamics
# (`joint.extra_views`). A point already done is skipped.
#   bash experiments/research/reference/image-landscape.sh SCENE [SEED=10] [EXTRA_VIEW]
# Writes runs/land/<scene>-s<seed>/A (the warm-up) and g<gravity>-d<dissipation>[-<view>]/; the
# table: python3 experiments/research/reference/image-landscape.py
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 seed=${2:-10} extra=${3:-}
bin=${NF_BIN:-target/release/neurofluid-train}
data=${BED_DATA:-data/bed-particles}/$scene
cfg=experiments/bed/$scene.toml
base=runs/land/$scene-s$seed
scene_sets=(--set "scene.path=\"$data\"" --set "seed=$seed")
mkdir -p "$base"
if [[ ! -f $base/A.done ]]; then
  "$bin" warmup "$cfg" "${scene_sets[@]}" --set "out_dir=\"$base/A\"" > "$base/A.log" 2>&1
  touch "$base/A.done"
fi
view_sets=() suffix=
if [[ -n $extra ]]; then
  view_sets=(--set "joint.extra_views=[\"$extra\"]") suffix=-$extra
fi
frozen=(--set joint.epochs=1 --set joint.bptt_steps=1 --set joint.log_every=1
  --set joint.ckpt_every=0 --set joint.preview_every=49 --set joint.foreground_rays=0
  --set joint.physnerf_optim.lr=0 --set joint.dlf_optim.lr=0
  --set joint.terms.anchor.weight=0 --set joint.terms.energy.weight=0
  --set 'dlf.energy_cap="none"' --set 'dlf.dissipation_frame="body"')
for g in 1.0 1.25 1.5 1.75 2.0; do
  for d in 0 0.02 0.05 0.15 0.4; do
    out=$base/g$g-d$d$suffix
    [[ -f $out.done ]] && continue
    rm -rf "$out" && mkdir -p "$out" && cp -r "$base/A/warmup" "$out/"
    "$bin" joint "$cfg" "${scene_sets[@]}" --set "out_dir=\"$out\"" "${frozen[@]}" \
      --set "dlf.gravity_scale=$g" --set "dlf.dissipation=$d" "${view_sets[@]}" > "$out.log" 2>&1
    touch "$out.done"
  done
done
