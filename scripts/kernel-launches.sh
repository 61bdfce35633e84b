#!/usr/bin/env bash
# Kernel launches per training step on a cubecl backend (wgpu, CUDA), counted from cubecl's own
# log: its profiling logger at level "minimal" writes one "Executing <kernel>" line per launch
# without timing anything (no synchronisation, so the step runs as it does untimed). The trainer
# marks each step's end at trace level (target neurofluid_train::step); the launches between two
# marks are that step's. Runs an experiment's warm-up for WARMUP_ITERS steps, then its joint stage
# until JOINT_SECONDS have passed, in a scratch folder (cubecl reads cubecl.toml from the working
# directory) whose experiments/, data/ and assets/ link to the repository's.
#
#   scripts/kernel-launches.sh BIN EXPERIMENT OUT [--device wgpu] [--set key=value ...]
#
# BIN is a neurofluid-train built with a cubecl backend; OUT a folder for the log and the summary
# (OUT/launches.txt: per stage the steps counted, the launches per step — median, the mean over
# the steps after the first, which compiles the kernels, and each step's — and the most launched
# kernels).
set -euo pipefail
bin=$(realpath "${1:?usage: kernel-launches.sh BIN EXPERIMENT OUT [args...]}")
experiment=${2:?usage: kernel-launches.sh BIN EXPERIMENT OUT [args...]}
out=${3:?usage: kernel-launches.sh BIN EXPERIMENT OUT [args...]}
shift 3
args=("$@")
((${#args[@]})) || args=(--device wgpu)
repo=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$out"
out=$(cd "$out" && pwd)
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
for d in experiments data assets target; do
    [ -e "$repo/$d" ] && ln -s "$repo/$d" "$scratch/$d"
done
cat >"$scratch/cubecl.toml" <<'EOF'
[profiling.logger]
level = "minimal"
stderr = true
EOF
log=$out/launches.log
cd "$scratch"
export RUST_LOG=info,neurofluid_train::step=trace
"$bin" warmup "$experiment" --fresh --set name=kernel-launches \
    --set "warmup.iters=${WARMUP_ITERS:-6}" --set warmup.ckpt_every=1000 \
    --set warmup.preview_every=0 "${args[@]}" 2>"$log" >/dev/null
# the joint stage for a while (stopped by the time limit: its steps so far are counted)
timeout "${JOINT_SECONDS:-120}" "$bin" joint "$experiment" --set name=kernel-launches \
    --set "warmup.iters=${WARMUP_ITERS:-6}" --set joint.ckpt_every=1000 \
    --set joint.preview_every=0 "${args[@]}" 2>>"$log" >/dev/null || true
python3 - "$log" <<'PY' | tee "$out/launches.txt"
import collections, re, statistics, sys
steps = []  # (stage, launches by kernel)
current = collections.Counter()
for line in open(sys.argv[1], errors="replace"):
    if line.startswith("Executing "):
        name = line.split()[1]
        current[re.sub(r"_[0-9a-f]{8}$", "", name)] += 1
    elif "step finished" in line:
        stage = re.search(r"stage=\"?(\w+)", line)
        steps.append((stage.group(1) if stage else "?", current))
        current = collections.Counter()
for stage in dict.fromkeys(s for s, _ in steps):
    counts = [c for s, c in steps if s == stage]
    totals = [sum(c.values()) for c in counts]
    later = totals[1:] or totals
    print(f"{stage}: {len(totals)} steps, launches per step median {statistics.median(totals):.0f}, "
          f"mean after the first {statistics.mean(later):.1f} (first {totals[0]})")
    # the joint stage's steps differ by their place in a BPTT window: each step's count
    print("    per step: " + " ".join(map(str, totals)))
    kernels = sum(counts[1:] or counts, collections.Counter())
    for name, n in kernels.most_common(12):
        print(f"    {n / len(later):7.1f}  {name}")
PY
