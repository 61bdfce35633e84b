#!/usr/bin/env bash
# Issue 71, item 3: the supervised reference under the walls on the built-in quick scenes
# (protocol: docs/notebook/2026-12-05-quick-reference.md) and, for its DLF† half, on the bed's
# scenes (docs/notebook/2026-12-06-bed-reference.md; the particles alone, BED_DATA, default
# data/bed-particles: `make_bed.py --no-render --out data/bed-particles`). One step per call, so
# a queue can order them; a step already done is skipped.
#   bash experiments/research/reference/quick-reference.sh STEP SCENE SEED
# STEP: D (the pretrained DLF under the walls, seed-free), T1 / T4 (the joint stage given the
# truth at the quick budget / 4×), T1h (T1 with DLF's weights held: the scalars and the renderer
# fitted to the truth and the images), S1 / S4 (DLF† fine-tuned on the training frames' truth,
# 300 / 1,200 steps); on a bed scene D, DA (the pretrained DLF under the scene's shipped material
# rules: A's D), S1 and S4 only. Writes runs/ref/<scene>-s<seed>-<STEP>(.log, .bpk, /); the table and the
# reference file: python3 experiments/research/reference/quick-table.py.
set -euo pipefail
cd "$(dirname "$0")/../../.."
step=$1 scene=$2 seed=${3:-10}
bin=${NF_BIN:-target/release/neurofluid-train}
cfg=experiments/research/reference/quick-walls-truth.toml
out=runs/ref/$scene-s$seed-$step
mkdir -p runs/ref
# the scene as the material probe's runs named it (their warm-ups are reused)
on_scene=(--set "scene.builtin=\"$scene\"" --set "scene.dir=\"data/${scene}_quick\""
  --set scene.generate.gravity=9.81)
data=data/${scene}_quick rollout_cfg=$cfg bed=
if [[ -f experiments/bed/$scene.toml ]]; then
  # a bed scene: its own config (as it ships: DA) with the material rule removed (the walls
  # alone, as $cfg's)
  bed=1 data=${BED_DATA:-data/bed-particles}/$scene rollout_cfg=experiments/bed/$scene.toml
  shipped=(--set "scene.path=\"$data\"")
  on_scene=("${shipped[@]}" --set dlf.gravity_scale=1.0 --set 'dlf.energy_cap="none"')
  [[ $step == D || $step == DA || $step == S1 || $step == S4 ]] ||
    { echo "$step: a bed scene has D, DA, S1 and S4 only" >&2; exit 2; }
fi
case $step in
  D)
    out=runs/ref/$scene-D
    [[ -f $out.log ]] || "$bin" rollout "$rollout_cfg" "${on_scene[@]}" > "$out.log" 2>&1 ;;
  DA)
    [[ $bed ]] || { echo "DA: bed scenes only" >&2; exit 2; }
    out=runs/ref/$scene-DA
    [[ -f $out.log ]] || "$bin" rollout "$rollout_cfg" "${shipped[@]}" > "$out.log" 2>&1 ;;
  T1|T1h|T4)
    [[ -f $out/eval/report.json ]] && exit 0
    epochs=(); [[ $step == T4 ]] && epochs=(--set joint.epochs=24
      --set 'joint.dlf_optim.schedule={ kind = "multi_step", milestones = [156, 228], gamma = 0.5 }')
    [[ $step == T1h ]] && epochs=(--set joint.physics.hold_dlf_epochs=6)
    # the warm-up depends on the scene, the seed and the renderer's settings alone: a copy of
    # another run's with the same three (WARMUP_FROM) saves it
    warm=${WARMUP_FROM:-runs/ref/$scene-s$seed-T1}/warmup
    if [[ ! -d $out/warmup && -d $warm && $warm != "$out/warmup" ]]; then
      mkdir -p "$out" && cp -r "$warm" "$out/"
    fi
    "$bin" run "$cfg" "${on_scene[@]}" --set "seed=$seed" --set "name=\"ref-$scene-s$seed-$step\"" \
      --set "out_dir=\"$out\"" "${epochs[@]}" >> "$out.log" 2>&1 ;;
  S1|S4)
    [[ -f $out.log ]] && grep -q "energy gained" "$out.log" && exit 0
    iters=300; [[ $step == S4 ]] && iters=1200
    "$bin" pretrain-dlf --data "$data" --init assets/dlf_pretrained/pretrained_model_weights.pt \
      --iterations $iters --batch-size 4 --lr 1e-4 --rules "$cfg" --backward-velocities --seed "$seed" \
      --validate-every $iters --output "$out.bpk" > "$out.train.log" 2>&1
    "$bin" rollout "$rollout_cfg" "${on_scene[@]}" --set "dlf.weights=\"$out.bpk\"" > "$out.log" 2>&1 ;;
  *) echo "STEP: D, DA, T1, T1h, T4, S1 or S4, not $step" >&2; exit 2 ;;
esac
