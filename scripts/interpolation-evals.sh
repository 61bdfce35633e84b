#!/bin/bash
# Evaluates a finished run at several `eval.weight_interpolation` fractions, without renders,
# each in its own folder: runs/interpolation/NAME/eval_a<fraction>/ (the run's warm-up and joint
# checkpoints are copied once to runs/interpolation/NAME, so the run itself is left as it was).
#
#   scripts/interpolation-evals.sh RUN_DIR NAME FRACTION... [--bin PATH]
#
# A fraction already evaluated is skipped. About 10 s per fraction at 100², 30 s at 400² (2 cores).
set -euo pipefail
bin=${NF_BIN:-target/debug/neurofluid-train}
src=$1; name=$2; shift 2
dest=runs/interpolation/$name
if [ ! -d "$dest/joint" ]; then
  mkdir -p "$dest"
  for f in config.resolved.toml metrics.csv metrics.jsonl; do cp "$src/$f" "$dest/"; done
  cp -r "$src/warmup" "$src/joint" "$dest/"
fi
for a in "$@"; do
  [ -f "$dest/eval_a$a/report.json" ] && continue
  "$bin" eval "$dest/config.resolved.toml" --set out_dir="$dest" --set eval.render=false \
    --set eval.animate=false --set eval.viewer=false --set eval.render_truth=false \
    --set eval.write_ply=false --set eval.weight_interpolation="$a" > "$dest/eval_a$a.log" 2>&1
  rm -rf "$dest/eval_a$a"
  mv "$dest/eval" "$dest/eval_a$a"
done
