#!/bin/bash
# Evaluates a finished run along the line from the pretrained DLF to its grounded one
# (`eval.interpolation_sweep`, no renders) in a copy of it, runs/interpolation/NAME/ (the run's
# warm-up and joint checkpoints are copied once, so the run itself is left as it was); the
# figures land in runs/interpolation/NAME/eval/report.{md,json} and interpolation.png.
#
#   scripts/analysis/interpolation-evals.sh RUN_DIR NAME
#
# NF_BIN names the binary (default target/debug/neurofluid-train). 1–3 min per run on 2 cores.
set -euo pipefail
bin=${NF_BIN:-target/debug/neurofluid-train}
src=$1
dest=runs/interpolation/$2
sweep="[0.0, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.75]"
if [ ! -d "$dest/joint" ]; then
  mkdir -p "$dest"
  for f in config.resolved.toml metrics.csv metrics.jsonl; do cp "$src/$f" "$dest/"; done
  cp -r "$src/warmup" "$src/joint" "$dest/"
fi
"$bin" eval "$dest/config.resolved.toml" --set out_dir="$dest" --set eval.render=false \
  --set eval.animate=false --set eval.viewer=false --set eval.render_truth=false \
  --set eval.write_ply=false --set eval.weight_interpolation=1.0 \
  --set "eval.interpolation_sweep=$sweep" > "$dest/eval.log" 2>&1
