#!/usr/bin/env bash
# A screen of one named variant of a bed config (experiments/bed/README.md rules 22-29): the
# variant's joint stage on a copy of A's warm-up (epochs-12: on a copy of A's whole joint stage,
# which it resumes at its last checkpoint) (A: the config as it ships at the same seed; run
# here first when A_RUN is not given), both evaluated without renders and without the refit (d and
# d′ are the joint stage's; the joint stage's terms and DLF's rules do not touch the warm-up). A run
# already evaluated is not run again; a stopped one resumes from its checkpoints.
# Variants: ballistic (rule 22), ballistic-viscous (rule 23), anchor-0 and anchor-depth (rule 24),
# silhouette (rule 25), rest-density (rule 26), rays-1024 (rule 27), epochs-12 (rule 28), truth
# and truth-free (rule 29, probes).
# Usage: VARIANT=name experiments/research/bed/screen.sh SCENE [A_RUN] [SEED=10] [OUT=runs/r22]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 a=${2:-} seed=${3:-10} out=${4:-runs/r22}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
quick=(--set seed="$seed" --set refit.enabled=false --set eval.render=false)
variant=${VARIANT:?VARIANT: ballistic, ballistic-viscous, anchor-0, anchor-depth, silhouette, rest-density, rays-1024, epochs-12, truth or truth-free}
case $variant in
  ballistic) rules=(--set 'dlf.free_flight="ballistic"') ;;
  ballistic-viscous)
    rules=(--set 'dlf.free_flight="ballistic"' --set dlf.viscosity=0.4 --set dlf.no_slip=true) ;;
  anchor-0) rules=(--set joint.anchor_weight=0) ;;
  anchor-depth) rules=(--set 'joint.anchor_along="depth"') ;;
  silhouette) rules=(--set joint.silhouette_weight=30) ;;
  rest-density) rules=(--set joint.rest_density_weight=1) ;;
  rays-1024) rules=(--set joint.rays=1024) ;;
  epochs-12) rules=(--set joint.epochs=12) resume=1 ;;
  truth) rules=(--set joint.truth_weight=1) ;;
  truth-free) rules=(--set joint.truth_weight=1 --set joint.anchor_weight=0 --set joint.energy_weight=0) ;;
  *) echo "VARIANT: ballistic, ballistic-viscous, anchor-0, anchor-depth, silhouette, rest-density, rays-1024, epochs-12, truth or truth-free, not $variant" >&2
     exit 2 ;;
esac
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
