#!/usr/bin/env bash
# Issue 71, candidate U12 (docs/notebook/2026-12-06-image-landscape.md): one configuration with no
# material rule whose physical scalars the images choose by a search: the bed config with the
# paper's gravity, no cap, no particle terms, the dissipation in the bodies' frame, and
# `[joint.physics.search]` over P7's grid (the gravity scale × the dissipation), the scalars then
# held (their rate 0) and DLF held, so d and d′ are the searched point's; one joint epoch (the
# renderer's training does not enter d or d′ with both held), evaluated without renders and
# without the refit. On a copy of P7's warm-up (image-landscape.sh) at the seed where there is one.
#   bash experiments/research/physics/search-runs.sh SCENE SEED
# Writes runs/one/U12-<scene>-s<seed>/ (quick-table.py reads it as candidate U12).
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 seed=$2
bin=${NF_BIN:-target/release/neurofluid-train}
out=runs/one/U12-$scene-s$seed
[[ -f $out/eval/report.json ]] && exit 0
mkdir -p runs/one
warm=runs/land/$scene-s$seed/A/warmup
if [[ ! -d $out/warmup && -f runs/land/$scene-s$seed/A.done ]]; then
  mkdir -p "$out" && cp -r "$warm" "$out/"
fi
"$bin" run "experiments/bed/$scene.toml" --set "scene.path=\"${BED_DATA:-data/bed-particles}/$scene\"" \
  --set "seed=$seed" --set "name=\"one-U12-$scene-s$seed\"" --set "out_dir=\"$out\"" \
  --set refit.enabled=false --set eval.render=false --set eval.write_ply=false \
  --set dlf.gravity_scale=1.0 --set 'dlf.energy_cap="none"' --set 'dlf.dissipation_frame="body"' \
  --set dlf.dissipation=0 --set dlf.viscosity=0 \
  --set joint.terms.anchor.weight=0 --set joint.terms.energy.weight=0 --set joint.epochs=1 \
  --set 'joint.physics.fit=["gravity_scale", "dissipation"]' --set joint.physics.hold_dlf_epochs=1 \
  --set 'joint.physics.optim={ lr = 0.0 }' \
  --set 'joint.physics.search={ gravity_scale = [1.0, 1.25, 1.5, 1.75, 2.0], dissipation = [0.0, 0.02, 0.05, 0.15, 0.4] }' \
  >> "$out.log" 2>&1
