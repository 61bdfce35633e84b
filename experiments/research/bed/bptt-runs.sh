#!/usr/bin/env bash
# experiments/bed/README.md rule 20 (twenty-third session): B, the bed config with BPTT over 8
# transitions and DLF's learning-rate milestones at the same iterations as the shipped ones, on a
# copy of A's warm-up (A: the config as it ships, its run at the same seed), evaluated without
# renders and without the refit (d and d′ are the joint stage's). A run already evaluated is not
# run again; a stopped one resumes from its checkpoints. The runs list for scripts/bed-table.py is
# experiments/research/bed/bptt-runs.txt.
# Usage: experiments/research/bed/bptt-runs.sh SCENE A_RUN [SEED=10] [OUT=runs/r20]
set -euo pipefail
cd "$(dirname "$0")/../../.."
scene=$1 a=$2 seed=${3:-10} out=${4:-runs/r20}
bin=${NEUROFLUID_TRAIN:-target/debug/neurofluid-train}
b=$out/$scene-s$seed-bptt8
mkdir -p "$b"
[[ -d $b/warmup ]] || cp -r "$a/warmup" "$b/"
if [[ ! -f $b/eval/report.json ]]; then
  "$bin" run "experiments/bed/$scene.toml" --set seed="$seed" --set out_dir="$b" \
    --set joint.bptt_steps=8 --set 'joint.dlf_optim.schedule.milestones=[21, 31]' \
    --set refit.enabled=false --set eval.render=false >> "$b.log" 2>&1
fi
