#!/usr/bin/env bash
# Issue 71, item 1: gravity identified from images alone (the rule, written before these runs:
# docs/notebook/2026-12-05-physics-identification.md). Three gravities × seeds 10–12 of
# experiments/research/physics/gravity-id-watercube.toml; prints one line per run:
# G seed fitted_scale d(t<50) and the run folder.
#   bash experiments/research/physics/gravity-id-runs.sh [seeds...]
set -euo pipefail
bin=${NF_BIN:-target/release/neurofluid-train}
cfg=experiments/research/physics/gravity-id-watercube.toml
seeds=${*:-10 11 12}
for seed in $seeds; do
  for g in 6.54 9.81 14.72; do
    name="physics-id-g${g}-s${seed}"
    "$bin" run "$cfg" --set "name=\"$name\"" --set "seed=$seed" \
      --set "scene.dir=\"data/watercube_quick_g${g}\"" --set "scene.generate.gravity=$g" \
      > "runs/$name.log" 2>&1 || echo "run $name failed: runs/$name.log"
    python3 - "$g" "$seed" "runs/$name" <<'PY'
import json, re, sys
g, seed, run = sys.argv[1:]
rows = [json.loads(l) for l in open(f"{run}/metrics.jsonl")]
scale = [r["physics/gravity_scale"] for r in rows if r.get("stage") == "joint" and "physics/gravity_scale" in r]
d = re.search(r"^\| NeuroFluid \| ([0-9.]+)", open(f"{run}/eval/report.md").read(), re.M)
print(g, seed, scale[-1] if scale else None, d.group(1) if d else None, run, flush=True)
PY
  done
done
