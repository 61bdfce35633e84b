#!/usr/bin/env bash
# Issue 71: do the fitted scalars differ by material without the config saying which? (a probe,
# chooses nothing: docs/notebook/2026-12-05-physics-identification.md)
#   bash experiments/research/physics/material-probe.sh [seeds...]   (default 10)
set -euo pipefail
bin=${NF_BIN:-target/release/neurofluid-train}
cfg=experiments/research/physics/gravity-id-watercube.toml
seeds=${*:-10}
for seed in $seeds; do
for scene in honeycone watercube; do
  name="physics-material-$scene-s$seed"
  "$bin" run "$cfg" --set "name=\"$name\"" --set "seed=$seed" --set "scene.builtin=\"$scene\"" \
    --set "scene.dir=\"data/${scene}_quick\"" \
    --set 'joint.physics.fit=["gravity_scale", "viscosity", "dissipation"]' \
    > "runs/$name.log" 2>&1 || echo "run $name failed: runs/$name.log"
  python3 - "runs/$name" <<'PY'
import json, re, sys
run = sys.argv[1]
rows = [json.loads(l) for l in open(f"{run}/metrics.jsonl")]
last = [r for r in rows if r.get("stage") == "joint" and "physics/gravity_scale" in r][-1]
md = open(f"{run}/eval/report.md").read()
d = re.search(r"^\| NeuroFluid \| ([0-9.]+)", md, re.M).group(1)
dlf = re.search(r"^\| DLF \(pretrained baseline\) \| ([0-9.]+)", md, re.M).group(1)
print(run, {k: round(v, 4) for k, v in last.items() if k.startswith("physics/")}, "d", d, "DLF", dlf, flush=True)
PY
done
done
