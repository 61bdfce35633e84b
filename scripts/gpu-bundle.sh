#!/usr/bin/env bash
# Builds a bundle that runs NeuroFluid-rs on a GPU machine with no Rust toolchain and no network:
# the trainer, the two step benchmarks and the backend-generic test binaries, built here with the
# wgpu backend (Vulkan; on NVIDIA through the driver's Vulkan ICD) in the dev profile (as every
# figure in BENCHMARKS.md), stripped, packed with xz into parts of at most 60 MiB, with
# `run-on-gpu.sh` to run them there.
#
#   scripts/gpu-bundle.sh DIR
#   # then, on the GPU machine, in a copy of this repository (same commit):
#   DIR/run-on-gpu.sh DIR RESULTS [STEPS]   # STEPS: tests benches quick paper (default: all)
#
# The binaries find the repository's test data through the path they were built in; run-on-gpu.sh
# links that path to the copy it runs in. CUDA is not in the bundle: Burn 0.22's CUDA backend
# downloads an LLVM build from GitHub while it compiles (cubecl-cuda → cubecl-llvm →
# tracel-llvm-bundler), which fails where GitHub cannot be reached.
set -euo pipefail
out=${1:?usage: scripts/gpu-bundle.sh DIR}
root=$(git rev-parse --show-toplevel)
cd "$root"
features=neurofluid-train/wgpu
# the backend-generic tests that check numbers on the device (the float64 ones are refused on wgpu)
tests="dense_layer posenc indexed_rows backends conv_geometry fused_conv parity_forward
parity_backward parity_rollout parity_e2e_f32 parity_stages options_and_weights nerf_fit
supervised_dlf pipeline_resume pretrain_on_scene learning"
mkdir -p "$out"
rm -f "$out"/part-*.tar.xz
json=$(mktemp)
trap 'rm -f "$json"; rm -rf "$stage"' EXIT
stage=$(mktemp -d)
mkdir -p "$stage/bin"
# (the test build also builds the trainer's binary, with the same features)
cargo test --workspace --features $features --locked --no-run --message-format=json >"$json"
cargo bench --profile dev --workspace --features $features --locked --no-run \
    --bench train_step --bench dlf_step --message-format=json >>"$json"
python3 - "$json" "$stage/bin" $tests <<'PY'
import json, shutil, subprocess, sys
path, dest, wanted = sys.argv[1], sys.argv[2], set(sys.argv[3:])
found = {}
for line in open(path):
    if not line.startswith("{"):
        continue
    m = json.loads(line)
    exe = m.get("executable")
    if m.get("reason") != "compiler-artifact" or not exe:
        continue
    t = m["target"]
    name, kinds = t["name"], t["kind"]
    if ("test" in kinds and name in wanted) or "bench" in kinds or (
        "bin" in kinds and name == "neurofluid-train"
    ):
        found[name] = exe
missing = (wanted | {"train_step", "dlf_step", "neurofluid-train"}) - set(found)
if missing:
    sys.exit(f"not built: {sorted(missing)}")
for name, exe in sorted(found.items()):
    subprocess.run(["strip", "-o", f"{dest}/{name}", exe], check=True)
PY
echo "$root" >"$stage/build-root"
git rev-parse HEAD >"$stage/commit"
cp scripts/run-on-gpu.sh "$out/run-on-gpu.sh"
# Vulkan's loader, for a GPU machine that has none (Debian/Ubuntu package; best effort)
if command -v apt-get >/dev/null; then
    mkdir -p "$out/debs"
    (cd "$out/debs" && apt-get download libvulkan1 2>/dev/null) ||
        echo "libvulkan1 not fetched: put Vulkan's loader in $out/debs if the GPU machine lacks it"
fi
cp "$stage/build-root" "$stage/commit" "$out/"
# parts: the trainer and benchmarks with the core and DLF tests, then the rest
part() {
    local n=$1
    shift
    (cd "$stage/bin" && tar cf - "$@") | xz -T2 -6 --lzma2=dict=256MiB >"$out/part-$n.tar.xz"
    local size
    size=$(stat -c %s "$out/part-$n.tar.xz")
    echo "part-$n.tar.xz: $((size / 1048576)) MiB"
    if [ "$size" -gt $((60 * 1048576)) ]; then
        echo "part-$n.tar.xz is over 60 MiB: split the bundle further" >&2
        exit 1
    fi
}
part 1 neurofluid-train train_step dlf_step dense_layer posenc indexed_rows backends \
    conv_geometry fused_conv parity_forward parity_backward parity_rollout
part 2 parity_e2e_f32 parity_stages options_and_weights nerf_fit supervised_dlf \
    pipeline_resume pretrain_on_scene learning
echo "bundle in $out (commit $(cat "$out/commit"))"
