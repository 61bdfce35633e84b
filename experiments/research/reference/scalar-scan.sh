#!/usr/bin/env bash
# Issue 71, item 3: P, the best a fit of the physical scalars with DLF held can reach on a bed
# scene (docs/notebook/2026-12-06-bed-reference.md): the pretrained DLF rolled out under the
# walls with the gravity scale and the dissipation (the box's frame) set on a grid, viscosity 0;
# seed-free. FRAME=body takes the dissipation in each body's frame (`dlf.dissipation_frame`). A
# point already rolled out is skipped.
#   [FRAME=body] bash experiments/research/reference/scalar-scan.sh SCENE
# Writes runs/ref/<scene>-scan[-body]/g<gravity>-d<dissipation>.log; the table:
#   python3 experiments/research/reference/quick-table.py --bed
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1
bin=${NF_BIN:-target/release/neurofluid-train}
data=${BED_DATA:-data/bed-particles}/$scene
frame=${FRAME:-box}
out=runs/ref/$scene-scan
[[ $frame == box ]] || out=$out-$frame
mkdir -p "$out"
for g in 1.0 1.25 1.5 1.75 2.0; do
  for d in 0 0.02 0.05 0.15 0.4; do
    log=$out/g$g-d$d.log
    [[ -f $log ]] && grep -q "energy gained" "$log" && continue
    "$bin" rollout "experiments/bed/$scene.toml" --set "scene.path=\"$data\"" \
      --set 'dlf.energy_cap="none"' --set "dlf.gravity_scale=$g" --set "dlf.dissipation=$d" \
      --set "dlf.dissipation_frame=\"$frame\"" \
      > "$log" 2>&1
  done
done
