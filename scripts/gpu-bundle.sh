#!/usr/bin/env bash
# Builds a bundle that runs NeuroFluid-rs on a GPU machine with no Rust toolchain and no network:
# the trainer, the two step benchmarks and the backend-generic test binaries, built here with the
# wgpu backend as a GPU needs it (the `wgpu-base` and `vulkan` features: fusion, Vulkan's SPIR-V
# compiler; on NVIDIA through the driver's Vulkan ICD) in the `gpu` profile (release, no debug
# assertions: with them wgpu turns on its validation layers), stripped, packed with xz into parts
# of at most 36 MiB, with `run-on-gpu.sh` to run them there. Part 1 (the trainer and the two step
# benchmarks) is all that run-on-gpu.sh's default steps need.
#
#   scripts/gpu-bundle.sh DIR
#   GPU_BUNDLE_PARTS=1 scripts/gpu-bundle.sh DIR   # part 1 only: no test binaries to build
#   # then, on the GPU machine, in a copy of this repository (same commit):
#   DIR/run-on-gpu.sh DIR RESULTS [STEPS]   # STEPS: see run-on-gpu.sh (default: physnerf dlf quick)
#
# The binaries find the repository's test data through the path they were built in; run-on-gpu.sh
# links that path to the copy it runs in. CUDA is not in the bundle: Burn 0.22's CUDA backend
# downloads an LLVM build from GitHub while it compiles (cubecl-cuda → cubecl-llvm →
# tracel-llvm-bundler), which fails where GitHub cannot be reached.
set -euo pipefail
out=${1:?usage: scripts/gpu-bundle.sh DIR}
root=$(git rev-parse --show-toplevel)
cd "$root"
# wgpu with fusion and Vulkan's SPIR-V compiler, fixed kernel choices (autotune stalled on an
# H100: neurofluid-core's Cargo.toml); where a driver cannot take the SPIR-V compiler (Mesa
# 22.3's lavapipe crashes), GPU_BUNDLE_FEATURES=neurofluid-train/wgpu-base
features=${GPU_BUNDLE_FEATURES:-neurofluid-train/wgpu-base,neurofluid-train/vulkan}
# the backend-generic tests that check numbers on the device (the float64 ones are refused on
# wgpu): a test binary and the modules of it to run (none: all of it), one per line of the
# bundle's `tests` file
tests=(
    "core_tests dense_layer:: half_matmul:: posenc:: indexed_rows:: backends:: square_sums:: device_search:: device_pairs:: row_sum_scale::"
    "dlf_tests conv_geometry:: fused_conv:: parity_forward:: parity_backward:: parity_rollout::"
    "device_geometry"
    "train_tests supervised_dlf::"
    "dev_tests parity_e2e_f32:: parity_stages:: options_and_weights::"
    "device_search_render"
    "nerf_fit"
    "end_to_end pipeline_resume:: transfers:: pretrain_on_scene:: learning:: warmup_passes::"
)
# the binaries, in the parts they travel in: part 1 the trainer and the two step benchmarks, then
# the test binaries. Parts of at most 36 MiB (each binary holds Burn's kernels for flex and
# cubecl: 80–110 MB stripped; on 2026-12-02 the parts packed 33.3, 33.1 and 33.6 MiB), so that
# each fits beside the repository (26 MB) in a 64 MiB transfer; the parts may arrive one at a
# time and unpack into the same folder there.
parts=(
    "neurofluid-train train_step dlf_step"
    "core_tests dlf_tests device_geometry train_tests nerf_fit"
    "dev_tests device_search_render end_to_end"
)
wanted="${parts[*]:1}"
mkdir -p "$out"
rm -f "$out"/part-*.tar.xz
json=$(mktemp)
trap 'rm -f "$json"; rm -rf "$stage"' EXIT
stage=$(mktemp -d)
mkdir -p "$stage/bin"
# (the test build also builds the trainer's binary, with the same features)
profile=${GPU_BUNDLE_PROFILE:-gpu}
only_first=${GPU_BUNDLE_PARTS:-all}
if [ "$only_first" = 1 ]; then
    wanted=""
    tests=()
    cargo build --profile "$profile" --workspace --features $features --locked --bins \
        --message-format=json >"$json"
else
    cargo test --profile "$profile" --workspace --features $features --locked --no-run \
        --message-format=json >"$json"
fi
cargo bench --profile "$profile" --workspace --features $features --locked --no-run \
    --bench train_step --bench dlf_step --message-format=json >>"$json"
printf '%s\n' "${tests[@]}" | sed '/^$/d' >"$stage/tests"
python3 - "$json" "$stage/bin" "$stage/tests" $wanted <<'PY'
import json, shutil, subprocess, sys
path, dest, tests_list, wanted = sys.argv[1], sys.argv[2], sys.argv[3], set(sys.argv[4:])
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
    # the trainer's binary, not the test harness of its unit tests (also a "bin" of that name)
    if ("test" in kinds and name in wanted) or "bench" in kinds or (
        "bin" in kinds and name == "neurofluid-train" and not m["profile"]["test"]
    ):
        found[name] = exe
missing = (wanted | {"train_step", "dlf_step", "neurofluid-train"}) - set(found)
if missing:
    sys.exit(f"not built: {sorted(missing)}")
for name, exe in sorted(found.items()):
    subprocess.run(["strip", "-o", f"{dest}/{name}", exe], check=True)
# every module named in the tests list holds tests in its binary
for line in open(tests_list):
    binary, *modules = line.split()
    if binary not in found:
        sys.exit(f"the tests list names {binary}, which is in no part")
    listed = subprocess.run([found[binary], "--list"], capture_output=True, text=True, check=True)
    names = [l.split(": ")[0] for l in listed.stdout.splitlines() if l.endswith(": test")]
    empty = [m for m in modules if not any(n.startswith(m) for n in names)]
    if empty:
        sys.exit(f"{binary} has no tests in {empty}")
PY
echo "$root" >"$stage/build-root"
echo "$profile $features" >"$stage/profile"
git rev-parse HEAD >"$stage/commit"
cp scripts/run-on-gpu.sh "$out/run-on-gpu.sh"
# Vulkan's loader, for a GPU machine that has none (Debian/Ubuntu package; best effort)
if command -v apt-get >/dev/null; then
    mkdir -p "$out/debs"
    (cd "$out/debs" && apt-get download libvulkan1 2>/dev/null) ||
        echo "libvulkan1 not fetched: put Vulkan's loader in $out/debs if the GPU machine lacks it"
fi
cp "$stage/build-root" "$stage/commit" "$stage/profile" "$stage/tests" "$out/"
# two parts compress at a time
[ "$only_first" = 1 ] && parts=("${parts[0]}")
pack() {
    # shellcheck disable=SC2086 # the names are a list
    (cd "$stage/bin" && tar cf - $2) | xz -6 --lzma2=dict=256MiB >"$out/part-$1.tar.xz"
}
for ((i = 0; i < ${#parts[@]}; i += 2)); do
    pack $((i + 1)) "${parts[i]}" &
    if ((i + 1 < ${#parts[@]})); then pack $((i + 2)) "${parts[i + 1]}" & fi
    wait
done
for f in "$out"/part-*.tar.xz; do
    size=$(stat -c %s "$f")
    echo "${f##*/}: $((size / 1048576)) MiB"
    if [ "$size" -eq 0 ]; then
        echo "${f##*/} is empty: packing failed" >&2
        exit 1
    fi
    if [ "$size" -gt $((36 * 1048576)) ]; then
        echo "${f##*/} is over 36 MiB: split that part" >&2
        exit 1
    fi
done
echo "bundle in $out (commit $(cat "$out/commit"))"
