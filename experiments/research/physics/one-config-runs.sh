#!/usr/bin/env bash
# Issue 71, item 2: the quick screen of one configuration (docs/notebook/2026-12-05-quick-reference.md):
# U1 (experiments/research/physics/one-config.toml) and A (the shipped quick config of the
# scene's material) on the quick WaterCube and HoneyCone, on copies of the material probe's
# warm-ups (same scene, seed and renderer settings) where the resume check allows, evaluated
# without renders.
#   bash experiments/research/physics/one-config-runs.sh VARIANT SCENE SEED    (VARIANT: U0N, U0NB, U1, U2, U4, U4N, U5, U5a, U5b, U9 or A)
# (U4: U1 with the anchor and the energy prior; U4N: U4 with joint.input_noise = 0.1; U0N: U0
# with joint.input_noise = 0.1; U0NB: U0N with the dissipation in the bodies' frame; U5: U0NB for
# 3 epochs, then DLF grounded under the anchor and the energy prior with the scalars held; U5a:
# the same sets, run with the anchor that leaves the fitted scalars alone; U5b: U5a with the
# scalars' rate × 0.1 over epoch 3; U9: U5a without the viscosity fitted)
# (U10 and U11, with joint.physics.settle and joint.physics.shrink, ran at fba426a's code, where
# they are; both options were retired)
# (U6, U7 and U8, with the free flight, ran at 9b78745's code and are in 6b5d68d; the option was
# retired again)
# (U0 is the material probe: experiments/research/physics/material-probe.sh)
set -euo pipefail
cd "$(dirname "$0")/../../.."
variant=$1 scene=$2 seed=$3
bin=${NF_BIN:-target/release/neurofluid-train}
out=runs/one/$variant-$scene-s$seed
variant_sets=()
anchor_energy=(--set joint.terms.anchor.weight=0.1 --set joint.terms.energy.weight=0.005)
case $variant in
  U1) cfg=experiments/research/physics/one-config.toml ;;
  U2) cfg=experiments/research/physics/one-config.toml
    variant_sets=(--set joint.physics.hold_dlf_epochs=6 --set 'joint.physics.fit=["gravity_scale", "dissipation"]') ;;
  U4) cfg=experiments/research/physics/one-config.toml
    variant_sets=("${anchor_energy[@]}") ;;
  U4N) cfg=experiments/research/physics/one-config.toml
    variant_sets=("${anchor_energy[@]}" --set joint.input_noise=0.1) ;;
  U0N) cfg=experiments/research/physics/one-config.toml
    variant_sets=(--set joint.physics.hold_dlf_epochs=6 --set joint.input_noise=0.1) ;;
  U0NB) cfg=experiments/research/physics/one-config.toml
    variant_sets=(--set joint.physics.hold_dlf_epochs=6 --set joint.input_noise=0.1
      --set 'dlf.dissipation_frame="body"') ;;
  U5|U5a|U5b|U9) cfg=experiments/research/physics/one-config.toml
    # 13 updates an epoch (bptt_steps 4): the scalars' rate × 1e-6 from update 39 (U5b: × 0.1 over
    # epoch 3, updates 26-38, first), DLF's halved at 1/2 and 3/4 of its own 39
    hold='{ kind = "multi_step", milestones = [38], gamma = 1e-6 }'
    [[ $variant == U5b ]] && hold='{ kind = "piecewise", boundaries = [25, 38], factors = [0.1, 1e-6] }'
    variant_sets=("${anchor_energy[@]}" --set joint.input_noise=0.1 --set 'dlf.dissipation_frame="body"'
      --set joint.physics.hold_dlf_epochs=3
      --set "joint.physics.optim={ lr = 0.05, schedule = $hold }")
    [[ $variant == U9 ]] && variant_sets+=(--set 'joint.physics.fit=["gravity_scale", "dissipation"]') ;;
  A) cfg=experiments/quick-$scene.toml ;;
  *) echo "VARIANT: U0N, U0NB, U1, U2, U4, U4N, U5, U5a, U5b, U9 or A, not $variant" >&2; exit 2 ;;
esac
[[ -f $out/eval/report.json ]] && exit 0
warm=runs/physics-material-$scene-s$seed/warmup
# the shipped water config adds warm-up views at every frame (NeRF-T's), which the resume check
# counts as another scene: it warms up on its own
if [[ ! -d $out/warmup && -d $warm && $cfg != experiments/quick-watercube.toml ]]; then
  mkdir -p "$out" && cp -r "$warm" "$out/"
fi
"$bin" run "$cfg" --set "scene.builtin=\"$scene\"" --set "scene.dir=\"data/${scene}_quick\"" \
  --set scene.generate.gravity=9.81 \
  --set "seed=$seed" --set "name=\"one-$variant-$scene-s$seed\"" --set "out_dir=\"$out\"" \
  --set eval.render=false --set eval.write_ply=false "${variant_sets[@]}" >> "$out.log" 2>&1
