#!/usr/bin/env bash
# Issue 71, candidate U12 (docs/notebook/2026-12-06-image-landscape.md): one configuration with no
# material rule whose physical scalars the images choose by a search: the bed config with the
# paper's gravity, no cap, no particle terms, the dissipation in the bodies' frame, and
# `[joint.physics.search]` over P7's grid (the gravity scale × the dissipation), the scalars then
# held (their rate 0) and DLF held, so d and d′ are the searched point's; one joint epoch (the
# renderer's training does not enter d or d′ with both held), evaluated without renders and
# without the refit. On a copy of P7's warm-up (image-landscape.sh) at the seed where there is one.
# OBJECTIVE=silhouette scores the search by the training view's silhouette instead of the image
# loss: candidate U13 (P8/U13 in the same notebook), on a copy of P7's, U12's or U13's warm-up.
# (U14, OBJECTIVE=silhouette_motion, ran at 3367c4d's code; the objective was retired.)
# GROUND=1 (probe P10, with the silhouette): after the search, with the scalars held, DLF grounded
# over the config's epochs under the water config's particle terms (the anchor 0.1, the energy
# prior 0.005) on every scene: U15. ANCHOR=W (probe P11) grounds under the anchor's weight W
# instead (runs/one/U15-anchorW-…).
# RIG=2|4 (probe P12, with the silhouette): the joint stage's rig of 2 or 4 views
# (experiments/research/bed/rig-views.py), which the search scores too: runs/one/U13-rig<RIG>-…
# (with GROUND=1: U15-rig<RIG>-…, the one config on that rig).
# A built-in quick scene (watercube, honeycone) runs its quick config (experiments/quick-<scene>.toml)
# with the same changes, its warm-up made by the run.
#   [OBJECTIVE=silhouette [GROUND=1]] bash experiments/research/physics/search-runs.sh SCENE SEED
# Writes runs/one/U12-<scene>-s<seed>/ (U13-… with the silhouette, U15-… grounded; quick-table.py
# and image-landscape.py read them).
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 seed=$2
bin=${NF_BIN:-target/release/neurofluid-train}
objective=${OBJECTIVE:-image}
case $objective in
  image) cand=U12 ;; silhouette) cand=U13 ;;
  *) echo "OBJECTIVE: image or silhouette" >&2; exit 2 ;;
esac
held=(--set joint.terms.anchor.weight=0 --set joint.terms.energy.weight=0 --set joint.epochs=1
  --set joint.physics.hold_dlf_epochs=1)
if [[ ${GROUND:-} == 1 ]]; then
  [[ $cand == U13 ]] || { echo "GROUND=1 goes with OBJECTIVE=silhouette" >&2; exit 2; }
  cand=U15 anchor=${ANCHOR:-0.1}
  [[ $anchor == 0.1 ]] || cand=U15-anchor$anchor
  held=(--set joint.terms.anchor.weight=$anchor --set joint.terms.energy.weight=0.005
    --set joint.physics.hold_dlf_epochs=0)
fi
rig=()
if [[ -n ${RIG:-} ]]; then
  [[ $cand == U13 || $cand == U15 ]] || { echo "RIG goes with OBJECTIVE=silhouette" >&2; exit 2; }
  cand=$cand-rig$RIG
  rig=(--set "joint.extra_views=$(python3 experiments/research/bed/rig-views.py \
    "${BED_DATA:-data/bed-particles}/$scene" "$RIG")")
fi
out=runs/one/$cand-$scene-s$seed
[[ -f $out/eval/report.json ]] && exit 0
mkdir -p runs/one
if [[ ! -d $out/warmup ]]; then
  if [[ -f runs/land/$scene-s$seed/A.done ]]; then
    mkdir -p "$out" && cp -r "runs/land/$scene-s$seed/A/warmup" "$out/"
  else
    for from in U12 U13 U14 U15; do
      if [[ $cand != "$from" && -f runs/one/$from-$scene-s$seed/eval/report.json ]]; then
        mkdir -p "$out" && cp -r "runs/one/$from-$scene-s$seed/warmup" "$out/" && break
      fi
    done
  fi
fi
if [[ -f experiments/bed/$scene.toml ]]; then
  scene_sets=("experiments/bed/$scene.toml" --set "scene.path=\"${BED_DATA:-data/bed-particles}/$scene\"")
else
  scene_sets=("experiments/quick-$scene.toml")
fi
"$bin" run "${scene_sets[@]}" \
  --set "seed=$seed" --set "name=\"one-$cand-$scene-s$seed\"" --set "out_dir=\"$out\"" \
  --set refit.enabled=false --set eval.render=false --set eval.write_ply=false \
  --set dlf.gravity_scale=1.0 --set 'dlf.energy_cap="none"' --set 'dlf.dissipation_frame="body"' \
  --set dlf.dissipation=0 --set dlf.viscosity=0 \
  "${held[@]}" "${rig[@]}" --set 'joint.physics.fit=["gravity_scale", "dissipation"]' \
  --set 'joint.physics.optim={ lr = 0.0 }' \
  --set "joint.physics.search={ objective = \"$objective\", gravity_scale = [1.0, 1.25, 1.5, 1.75, 2.0], dissipation = [0.0, 0.02, 0.05, 0.15, 0.4] }" \
  >> "$out.log" 2>&1
