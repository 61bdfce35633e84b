#!/usr/bin/env bash
# Runs a bundle made by scripts/gpu-bundle.sh on a GPU machine, in a copy of the repository at the
# bundle's commit: the backend-generic tests on wgpu, the PhysNeRF and DLF step benchmarks (wgpu,
# then the machine's CPU for the same-run reference), the quick main job on wgpu, and the
# paper-scale WaterCube for PAPER_SECONDS (default 300; a second call resumes it from its
# checkpoints). Logs and a summary go to RESULTS.
#
#   BUNDLE/run-on-gpu.sh BUNDLE RESULTS [tests] [benches] [quick] [paper]
set -uo pipefail
bundle=$(cd "${1:?usage: run-on-gpu.sh BUNDLE RESULTS [STEPS]}" && pwd)
results=${2:?usage: run-on-gpu.sh BUNDLE RESULTS [STEPS]}
shift 2
steps=${*:-tests benches quick paper}
mkdir -p "$results"
results=$(cd "$results" && pwd)
summary=$results/summary.txt
say() { echo "$*" | tee -a "$summary"; }

# the parts present (one or all; parts unpacked by an earlier call stay in BUNDLE/bin)
mkdir -p "$bundle/bin"
for p in "$bundle"/part-*.tar.xz; do
    [ -e "$p" ] && { xz -dc "$p" | tar xf - -C "$bundle/bin" || exit 1; }
done
# the binaries read test data and assets through the path they were built in
built=$(cat "$bundle/build-root")
if [ "$built" != "$PWD" ] && [ ! -e "$built" ]; then
    mkdir -p "$(dirname "$built")" && ln -s "$PWD" "$built" || exit 1
fi
# Vulkan: the loader (carried .deb files in BUNDLE/debs when the machine has none) and NVIDIA's ICD
if ! ldconfig -p | grep -q 'libvulkan\.so\.1'; then
    for f in "$bundle"/debs/*.deb; do [ -e "$f" ] && dpkg -x "$f" /; done
    ldconfig
fi
nv_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -e "$nv_icd" ] &&
    ! ls /usr/share/vulkan/icd.d/nvidia* /etc/vulkan/icd.d/nvidia* >/dev/null 2>&1; then
    export VK_DRIVER_FILES=$nv_icd
fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
bin=$bundle/bin
say "commit $(cat "$bundle/commit"); $(date -u +%FT%TZ); $(nproc) CPUs"
command -v nvidia-smi >/dev/null && say "$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader)"

timed() { # label log command...: wall seconds and exit status into the summary
    local label=$1 log=$2
    shift 2
    local exe
    for exe in "$@"; do [[ $exe == "$bin"/* ]] && break; done
    if [[ $exe == "$bin"/* ]] && [ ! -x "$exe" ]; then
        say "$label: skipped, ${exe##*/} is in a part not unpacked here"
        return
    fi
    local t0=$SECONDS
    "$@" >>"$log" 2>&1
    local rc=$?
    say "$label: exit $rc, $((SECONDS - t0)) s"
}

for step in $steps; do
    case $step in
    tests)
        for t in dense_layer posenc indexed_rows backends conv_geometry fused_conv parity_forward \
            parity_backward parity_rollout parity_e2e_f32 parity_stages options_and_weights \
            nerf_fit supervised_dlf pipeline_resume pretrain_on_scene learning; do
            echo "== $t" >>"$results/tests.log"
            NEUROFLUID_TEST_DEVICE=wgpu timed "test $t" "$results/tests.log" "$bin/$t"
            [ -x "$bin/$t" ] && grep '^test result' "$results/tests.log" | tail -1 | sed 's/^/  /' | tee -a "$summary"
        done
        ;;
    benches)
        for d in wgpu cpu; do
            timed "train_step $d" "$results/benches.log" "$bin/train_step" --bench --device "$d"
            timed "dlf_step $d" "$results/benches.log" \
                "$bin/dlf_step" --device "$d" --repeats 3 --sizes 8000 32000
        done
        ;;
    quick)
        rss=()
        [ -x /usr/bin/time ] && rss=(/usr/bin/time -v)
        timed "quick main job (wgpu)" "$results/quick.log" "${rss[@]}" \
            "$bin/neurofluid-train" run experiments/quick-watercube.toml --device wgpu --fresh \
            --set name=gpu-quick
        ;;
    paper)
        timed "paper-scale WaterCube (wgpu, ${PAPER_SECONDS:-300} s at most)" "$results/paper.log" \
            timeout "${PAPER_SECONDS:-300}" "$bin/neurofluid-train" run \
            experiments/paper-watercube.toml --device wgpu --set name=gpu-paper
        ;;
    *) say "unknown step $step (tests, benches, quick, paper)" ;;
    esac
done
