#!/usr/bin/env bash
# experiments/bed/README.md rule 22 (twenty-seventh session), step 2: B, the bed config with
# `dlf.free_flight = "ballistic"`, on a copy of A's warm-up (A: the config as it ships at the
# same seed; run here first when A_RUN is not given), both evaluated without renders and without
# the refit (d and d′ are the joint stage's). A run already evaluated is not run again; a stopped
# one resumes from its checkpoints. The runs list for scripts/bed-table.py is
# experiments/bed/free-flight-runs.txt. VARIANT=ballistic-viscous runs rule 23's C instead of B
# (the same, with `dlf.viscosity = 0.4` and `dlf.no_slip = true`).
# Usage: [VARIANT=ballistic-viscous] experiments/bed/free-flight-runs.sh SCENE [A_RUN] [SEED=10] [OUT=runs/r22]
set -euo pipefail
cd "$(dirname "$0")/../.."
scene=$1 a=${2:-} seed=${3:-10} out=${4:-runs/r22}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
quick=(--set seed="$seed" --set refit.enabled=false --set eval.render=false)
if [[ -z $a ]]; then
  a=$out/$scene-s$seed-A
  if [[ ! -f $a/eval/report.json ]]; then
    "$bin" run "experiments/bed/$scene.toml" "${quick[@]}" --set out_dir="$a" >> "$a.log" 2>&1
  fi
fi
variant=${VARIANT:-ballistic}
rules=(--set 'dlf.free_flight="ballistic"')
case $variant in
  ballistic) ;;
  ballistic-viscous) rules+=(--set dlf.viscosity=0.4 --set dlf.no_slip=true) ;;
  *) echo "VARIANT: ballistic or ballistic-viscous, not $variant" >&2; exit 2 ;;
esac
b=$out/$scene-s$seed-$variant
mkdir -p "$b"
[[ -d $b/warmup ]] || cp -r "$a/warmup" "$b/"
if [[ ! -f $b/eval/report.json ]]; then
  "$bin" run "experiments/bed/$scene.toml" "${quick[@]}" --set out_dir="$b" "${rules[@]}" \
    >> "$b.log" 2>&1
fi
