#!/usr/bin/env bash
# A screen of one named variant of a bed config (experiments/bed/README.md rules 22-29): the
# variant's joint stage on a copy of A's warm-up (epochs-12: on a copy of A's whole joint stage,
# which it resumes at its last checkpoint) (A: the config as it ships at the same seed; run
# here first when A_RUN is not given), both evaluated without renders and without the refit (d and
# d′ are the joint stage's; the joint stage's terms and DLF's rules do not touch the warm-up). A run
# already evaluated is not run again; a stopped one resumes from its checkpoints.
# Variants of options still in the code: anchor-0 (rule 24), rays-1024 (rule 27), epochs-12
# (rule 28), truth and truth-free (rule 29, probes), one-config, one-config-u2, one-config-noise
# and one-config-noise-body (issue 71: no material rule, the physical scalars fitted by the images
# with DLF held; U0, U2, U0N and U0NB of docs/notebook/2026-12-05-quick-reference.md) and
# one-config-fit-then-ground (U5: U0NB for 3 epochs, then DLF grounded under the anchor and the
# energy prior with the scalars held; -a: U5a, the same run with the anchor that leaves the fitted
# scalars alone; -b: U5b, U5a with the scalars' rate × 0.1 over epoch 3; -c: U5c, U5b with the one
# config's 4 transitions unrolled on every scene, so its schedules are the quick U5b's; -u9: U9,
# U5a without the viscosity fitted). one-config-settle-u10 and one-config-shrink-u11 (U10: U9 with
# the fit held once it had settled, joint.physics.settle = 0.01, at the latest after 6 of 9 epochs,
# DLF grounded after it; U11: U10 with joint.physics.shrink = 0.01) ran at fba426a's code, where
# they are; both options failed and were retired. The free flight's variants
# (one-config-free-flight[-c|-u7], one-config-fit-then-ground-ff: U6, U6c, U7, U8) ran at
# 9b78745's code and are in 6b5d68d; the option was retired again. The variants of rules 22-26 screened options since retired
# (docs/notebook/2026-12-05-retired-options.md lists them and the commits that had them).
# Usage: VARIANT=name experiments/research/bed/screen.sh SCENE [A_RUN] [SEED=10] [OUT=runs/r22]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 a=${2:-} seed=${3:-10} out=${4:-runs/r22}
bin=${NEUROFLUID_TRAIN:-target/release/neurofluid-train}
quick=(--set seed="$seed" --set refit.enabled=false --set eval.render=false)
variants="anchor-0, rays-1024, epochs-12, truth, truth-free, one-config, one-config-u2, one-config-noise, one-config-noise-body, one-config-fit-then-ground, one-config-fit-then-ground-a, one-config-fit-then-ground-b, one-config-fit-then-ground-c or one-config-fit-then-ground-u9"
variant=${VARIANT:?VARIANT: $variants}
# no material rule; the fitted scalars with DLF held and Adam at 0.05
no_material_rule=(--set dlf.gravity_scale=1.0 --set 'dlf.energy_cap="none"'
  --set joint.terms.anchor.weight=0 --set joint.terms.energy.weight=0)
held=(--set joint.physics.hold_dlf_epochs=6 --set 'joint.physics.optim={ lr = 0.05 }')
three=(--set 'joint.physics.fit=["gravity_scale", "viscosity", "dissipation"]')
two=(--set 'joint.physics.fit=["gravity_scale", "dissipation"]')
case $variant in
  anchor-0) rules=(--set joint.terms.anchor.weight=0) ;;
  rays-1024) rules=(--set joint.rays=1024) ;;
  epochs-12) rules=(--set joint.epochs=12) resume=1 ;;
  truth) rules=(--set joint.terms.truth.weight=1) ;;
  truth-free) rules=(--set joint.terms.truth.weight=1 --set joint.terms.anchor.weight=0
    --set joint.terms.energy.weight=0) ;;
  one-config) rules=("${no_material_rule[@]}" "${three[@]}" "${held[@]}") ;;
  one-config-u2) rules=("${no_material_rule[@]}" "${two[@]}" "${held[@]}") ;;
  one-config-noise) rules=("${no_material_rule[@]}" "${three[@]}" "${held[@]}"
    --set joint.input_noise=0.1) ;;
  one-config-noise-body) rules=("${no_material_rule[@]}" "${three[@]}" "${held[@]}"
    --set joint.input_noise=0.1 --set 'dlf.dissipation_frame="body"') ;;
  one-config-fit-then-ground|one-config-fit-then-ground-[abc]|one-config-fit-then-ground-u9)
    # updates an epoch: one per window of bptt_steps transitions of 49 (the scene's config; -c:
    # the one config's 4 on every scene)
    bptt=$(sed -n 's/^bptt_steps *= *\([0-9]*\).*/\1/p' "experiments/bed/$scene.toml")
    [[ $variant == *-c ]] && bptt=4
    per=$(( (49 + bptt - 1) / bptt ))
    # the scalars held from epoch 4 (their rate × 1e-6); -b, -c: at × 0.1 over epoch 3 first
    dlf_milestones="$((3 * per / 2)), $((9 * per / 4))"
    # -c: the quick one config's DLF schedule (experiments/research/physics/one-config.toml)
    [[ $variant == *-c ]] && dlf_milestones="19, 28"
    if [[ $variant == *-[bc] ]]; then
      hold="{ kind = \"piecewise\", boundaries = [$((2 * per - 1)), $((3 * per - 1))], factors = [0.1, 1e-6] }"
    else
      hold="{ kind = \"multi_step\", milestones = [$((3 * per - 1))], gamma = 1e-6 }"
    fi
    fitted=("${three[@]}")
    [[ $variant == *-u9 ]] && fitted=("${two[@]}")
    rules=("${no_material_rule[@]}" "${fitted[@]}" --set joint.input_noise=0.1
      --set 'dlf.dissipation_frame="body"' --set joint.terms.anchor.weight=0.1
      --set joint.terms.energy.weight=0.005 --set joint.physics.hold_dlf_epochs=3
      --set "joint.physics.optim={ lr = 0.05, schedule = $hold }"
      --set "joint.dlf_optim.schedule={ kind = \"multi_step\", milestones = [$dlf_milestones], gamma = 0.5 }")
    [[ $variant == *-c ]] && rules+=(--set joint.bptt_steps=4) ;;
  *) echo "VARIANT: $variants, not $variant" >&2
     exit 2 ;;
esac
mkdir -p "$out"
if [[ -z $a ]]; then
  a=$out/$scene-s$seed-A
  if [[ ! -f $a/eval/report.json ]]; then
    "$bin" run "experiments/bed/$scene.toml" "${quick[@]}" --set out_dir="$a" >> "$a.log" 2>&1
  fi
fi
b=$out/$scene-s$seed-$variant
mkdir -p "$b"
[[ -d $b/warmup ]] || cp -r "$a/warmup" "$b/"
if [[ -n ${resume:-} && ! -d $b/joint ]]; then
  cp -r "$a/joint" "$a/metrics.jsonl" "$a/metrics.csv" "$b/"
fi
if [[ ! -f $b/eval/report.json ]]; then
  "$bin" run "experiments/bed/$scene.toml" "${quick[@]}" --set out_dir="$b" "${rules[@]}" \
    >> "$b.log" 2>&1
fi
