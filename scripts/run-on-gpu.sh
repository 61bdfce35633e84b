#!/usr/bin/env bash
# Runs a bundle made by scripts/gpu-bundle.sh on a GPU machine, in a copy of the repository at the
# bundle's commit, in priority order within a time budget (BUDGET seconds, default 540: one
# 10-minute device call with room to unpack), each step cut at what is left:
#
#   physnerf  the PhysNeRF training step on wgpu (1,024 rays, 64 + 128 samples, 10,164 particles,
#             with its host–device copies), the project's PyTorch reference of the same step on
#             CUDA (where python3 has torch with CUDA), then the same step on this machine's CPU
#   dlf       DLF forward and forward+backward at 8k and 32k fluid particles, wgpu then CPU
#   physnerf-wgpu, dlf-wgpu  the same on wgpu alone (a second call, the references measured);
#             physnerf-wgpu also with the dense layers in one matmul over every row (--split-rows 0)
#   half      the PhysNeRF step on wgpu with the dense layers' matmuls on 16-bit operands (f16,
#             then bf16: the tensor cores; `--matmul`), its kernel profile with f16 (do the
#             matmul kernels' names say cmma?), and the quick main job's warm-up with f16
#             (HALF_QUICK_SECONDS, default 120)
#   search    the PhysNeRF step on wgpu with the ball query on the GPU (`--search device`), with
#             f32 and then f16 operands, the DLF step with its pairs found on the GPU, and the
#             quick main job's warm-up with both
#             (SEARCH_QUICK_SECONDS, default 120; `neighbour_search = "device"`)
#   split     the PhysNeRF step on wgpu with the dense layers' rows in blocks of each of
#             SPLIT_ROWS (default "2048 8192 16384"; the default block is 4,096)
#   quick     the quick main job on wgpu, GPU utilisation sampled every second (per stage in the
#             summary)
#   launches  kernel launches per warm-up and joint step of the quick main job
#             (scripts/kernel-launches.sh: cubecl's untimed launch log split at the trainer's
#             step marks; LAUNCHES_JOINT_SECONDS, default 60)
#   threads   each thread's CPU time per warm-up and joint step of the quick main job
#             (scripts/thread-times.py: the training thread, cubecl's device threads; which one
#             bounds a step; THREADS_WARMUP_ITERS, default 60, THREADS_JOINT_SECONDS, default 60)
#   profile   one small PhysNeRF step with CUBECL_DEBUG_OPTION=profile: cubecl's log of every
#             kernel launch, timed on the device, summed by kernel (scripts/cubecl-profile-summary.py)
#   dlfprofile  the same for DLF steps at 8k fluid particles (a warm-up, one forward, one
#             forward+backward)
#   tests     the backend-generic tests on wgpu (parts 2 and 3 of the bundle)
#   paper     the paper-scale WaterCube for PAPER_SECONDS (default 300; a second call resumes it)
#
#   BUNDLE/run-on-gpu.sh BUNDLE RESULTS [STEP...]   # default: physnerf dlf profile dlfprofile quick
#
# Logs go to RESULTS, one line per run to RESULTS/summary.txt.
set -uo pipefail
bundle=$(cd "${1:?usage: run-on-gpu.sh BUNDLE RESULTS [STEP...]}" && pwd)
results=${2:?usage: run-on-gpu.sh BUNDLE RESULTS [STEP...]}
shift 2
steps=${*:-physnerf dlf profile dlfprofile quick}
budget=${BUDGET:-540}
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
# NVIDIA's Vulkan ICD, headless: a manifest for the driver's EGL library (libEGL_nvidia.so.0
# holds the Vulkan driver too). The driver's own manifest names libGLX_nvidia.so.0, which on an
# H100 container without an X server gave the loader no vkCreateInstance ("Found no drivers",
# wgpu: "no adapter found"); it is the fallback where the EGL library is absent.
if [ -z "${VK_DRIVER_FILES:-}" ]; then
    lib=$(ldconfig -p | awk '/libEGL_nvidia\.so\.0/{print $NF; exit}')
    [ -z "$lib" ] && lib=$(find / -xdev -name 'libEGL_nvidia.so.0' 2>/dev/null | head -1)
    if [ -n "$lib" ]; then
        icd=/tmp/nvidia_egl_icd.json
        printf '{"file_format_version":"1.0.0","ICD":{"library_path":"%s","api_version":"1.3.0"}}\n' \
            "$lib" >"$icd"
    else
        icd=$(find /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/nvidia \
            /usr/local/share/vulkan -name 'nvidia*.json' 2>/dev/null | head -1)
    fi
    [ -n "$icd" ] && export VK_DRIVER_FILES=$icd
fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
bin=$bundle/bin
say "commit $(cat "$bundle/commit"), profile and features $(cat "$bundle/profile" 2>/dev/null || echo dev); $(date -u +%FT%TZ); $(nproc) CPUs; budget ${budget} s"
command -v nvidia-smi >/dev/null && say "$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader)"
say "Vulkan ICD: ${VK_DRIVER_FILES:-none found}; NVIDIA_DRIVER_CAPABILITIES=${NVIDIA_DRIVER_CAPABILITIES:-unset}"

deadline=$((SECONDS + budget))
left() { echo $((deadline - SECONDS)); }

# label cap log command...: runs the command for at most min(cap, what is left of the budget)
# seconds; wall seconds and exit status (124: cut by the limit) into the summary
timed() {
    local label=$1 cap=$2 log=$3
    shift 3
    local exe
    for exe in "$@"; do [[ $exe == "$bin"/* ]] && break; done
    if [[ $exe == "$bin"/* ]] && [ ! -x "$exe" ]; then
        say "$label: skipped, ${exe##*/} is in a part not unpacked here"
        return
    fi
    local limit
    limit=$(left)
    ((cap < limit)) && limit=$cap
    if ((limit < 15)); then
        say "$label: skipped, the budget is spent"
        return
    fi
    echo "== $label ($(date -u +%FT%TZ), at most $limit s)" >>"$log"
    local t0=$SECONDS
    timeout "$limit" "$@" >>"$log" 2>&1
    local rc=$?
    say "$label: exit $rc, $((SECONDS - t0)) s"
    return $rc
}

# the summary lines a log's last run printed that start with one of the patterns
report() {
    local log=$1
    shift
    [ -e "$log" ] || return
    local pattern
    for pattern in "$@"; do
        awk '/^== /{buf=""} {buf=buf $0 "\n"} END{printf "%s", buf}' "$log" |
            grep -E "$pattern" | sed 's/^/    /' | tee -a "$summary"
    done
}

# label seconds tag key=value: the quick main job on wgpu with one setting for at most that long
# (RESULTS/quick-TAG.log), and its last warm-up steps into the summary
quick_start() {
    timed "quick main job, wgpu, $1 ($2 s at most)" "$2" "$results/quick-$3.log" \
        "$bin/neurofluid-train" run experiments/quick-watercube.toml --device wgpu --fresh \
        --set "name=gpu-quick-$3" --set "$4"
    grep -E 'warmup step [0-9]+' "$results/quick-$3.log" | tail -3 | sed 's/^/    /' |
        tee -a "$summary"
}

has_cuda_torch() {
    command -v python3 >/dev/null &&
        python3 -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)' 2>/dev/null
}

for step in $steps; do
    case $step in
    physnerf)
        log=$results/physnerf.log
        timed "PhysNeRF step, wgpu" 100 "$log" "$bin/train_step" --bench --device wgpu
        if (($? == 139)); then
            say "    the wgpu binary crashed (SIGSEGV): if in the Vulkan driver, rebuild the bundle" \
                "without Vulkan's compiler (GPU_BUNDLE_FEATURES=neurofluid-train/wgpu)"
        fi
        report "$log" "step \(forward|MLPs alone|host–device|forward [0-9]"
        if has_cuda_torch; then
            timed "PhysNeRF step, PyTorch reference on CUDA" 100 "$log" python3 \
                tests/data/physnerf/physnerf_reference.py bench --device cuda --repeats 3 \
                --modes gated all --out "$results/physnerf_torch_cuda.json"
            report "$log" "^ *(gated|all):"
        else
            say "PhysNeRF step, PyTorch reference on CUDA: skipped, no python3 with torch and CUDA"
        fi
        timed "PhysNeRF step, CPU" 60 "$log" "$bin/train_step" --bench --device cpu
        report "$log" "step \(forward"
        ;;
    physnerf-wgpu)
        log=$results/physnerf.log
        timed "PhysNeRF step, wgpu" 100 "$log" "$bin/train_step" --bench --device wgpu
        report "$log" "step \(forward|MLPs alone|host–device|forward [0-9]"
        timed "PhysNeRF step, wgpu, dense layers in one matmul" 100 "$log" "$bin/train_step" \
            --bench --device wgpu --split-rows 0
        report "$log" "step \(forward|MLPs alone"
        ;;
    half)
        log=$results/physnerf.log
        for m in f16 bf16; do
            timed "PhysNeRF step, wgpu, $m operands" 100 "$log" "$bin/train_step" --bench \
                --device wgpu --matmul "$m"
            report "$log" "step \(forward|MLPs alone|host–device"
        done
        timed "one small PhysNeRF step with f16 operands, cubecl's kernel profile" 60 \
            "$results/profile-f16.log" env CUBECL_DEBUG_OPTION=profile \
            CUBECL_DEBUG_LOG="$results/profile-f16-kernels.log" "$bin/train_step" --device wgpu \
            --matmul f16
        python3 scripts/cubecl-profile-summary.py "$results/profile-f16-kernels.log" --top 12 |
            sed 's/^/    /' | tee -a "$summary"
        quick_start "f16 operands" "${HALF_QUICK_SECONDS:-120}" f16 matmul=f16
        ;;
    search)
        log=$results/physnerf.log
        for m in f32 f16; do
            timed "PhysNeRF step, wgpu, ball query on the GPU, $m operands" 100 "$log" \
                "$bin/train_step" --bench --device wgpu --search device --matmul "$m"
            report "$log" "step \(forward|MLPs alone|host–device|forward [0-9]"
        done
        log=$results/dlf.log
        timed "DLF step, wgpu, pairs on the GPU" 100 "$log" "$bin/dlf_step" --device wgpu \
            --repeats 3 --sizes 8000 32000 --search device
        report "$log" "^\| [0-9]" "N = [0-9]+:" "^phases" "^check against"
        quick_start "searches on the GPU" "${SEARCH_QUICK_SECONDS:-120}" search \
            neighbour_search=device
        ;;
    split)
        log=$results/physnerf.log
        for rows in ${SPLIT_ROWS:-2048 8192 16384}; do
            timed "PhysNeRF step, wgpu, dense layers in blocks of $rows rows" 60 "$log" \
                "$bin/train_step" --bench --device wgpu --split-rows "$rows"
            report "$log" "step \(forward|MLPs alone"
        done
        ;;
    dlf | dlf-wgpu)
        log=$results/dlf.log
        devices="wgpu cpu"
        [ "$step" = dlf-wgpu ] && devices=wgpu
        for d in $devices; do
            timed "DLF step, $d" 100 "$log" "$bin/dlf_step" --device "$d" --repeats 3 \
                --sizes 8000 32000
            report "$log" "^\| [0-9]" "N = [0-9]+:" "^check against"
        done
        ;;
    quick)
        log=$results/quick.log
        util=$results/quick-gpu-util.txt
        : >"$util"
        sampler=
        if command -v nvidia-smi >/dev/null; then
            (while sleep 1; do
                echo "$(date -u +%s.%N) $(nvidia-smi --query-gpu=utilization.gpu \
                    --format=csv,noheader,nounits | head -1)"
            done) >>"$util" 2>/dev/null &
            sampler=$!
        fi
        rss=()
        [ -x /usr/bin/time ] && rss=(/usr/bin/time -v)
        timed "quick main job, wgpu" 600 "$log" "${rss[@]}" "$bin/neurofluid-train" run \
            experiments/quick-watercube.toml --device wgpu --fresh --set name=gpu-quick
        [ -n "$sampler" ] && kill "$sampler" 2>/dev/null
        report "$log" "^\| NeuroFluid|^\| DLF \(|Maximum resident"
        # each stage's step times by metrics row (the means over each row's steps): the first
        # rows hold the kernels' compilation and the first allocations
        if [ -s runs/gpu-quick/metrics.jsonl ] && command -v python3 >/dev/null; then
            python3 - runs/gpu-quick/metrics.jsonl <<'PY' | tee -a "$summary"
import json, statistics, sys
rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
for stage in dict.fromkeys(r.get("stage") for r in rows):
    timed = [(r["step"], r["step_s"]) for r in rows if r.get("stage") == stage and "step_s" in r]
    if not timed:
        continue
    first = ", ".join(f"to step {s} {t:.3f}" for s, t in timed[:4])
    rest = [t for _, t in timed[4:]]
    steady = f"; then median {statistics.median(rest):.3f} s over {len(rest)} rows" if rest else ""
    print(f"    {stage} seconds per step: {first}{steady}")
PY
        fi
        # GPU utilisation per stage: the log's stage lines (UTC) split the samples
        if [ -s "$util" ] && command -v python3 >/dev/null; then
            python3 - "$log" "$util" <<'PY' | tee -a "$summary"
import datetime, re, sys
log, util = sys.argv[1], sys.argv[2]
marks = []
for line in open(log, errors="replace"):
    m = re.match(r"(\d{4}-\d\d-\d\dT[\d:.]+)Z\s+INFO (warm-up|joint grounding|evaluating)", line)
    if m:
        t = datetime.datetime.fromisoformat(m.group(1)[:26]).replace(tzinfo=datetime.timezone.utc)
        marks.append((t.timestamp(), m.group(2)))
samples = []
for line in open(util):
    parts = line.split()
    if len(parts) == 2 and parts[1].isdigit():
        samples.append((float(parts[0]), int(parts[1])))
def stage(t):
    name = "before the warm-up"
    for start, n in marks:
        if t >= start:
            name = n
    return name
by = {}
for t, u in samples:
    by.setdefault(stage(t), []).append(u)
for name, us in by.items():
    busy = sum(u > 50 for u in us) / len(us)
    print(f"    GPU utilisation, {name}: mean {sum(us) / len(us):.0f} %, "
          f"{100 * busy:.0f} % of {len(us)} samples above 50 %")
PY
        fi
        ;;
    launches)
        timed "kernel launches per step, quick main job" \
            $((${LAUNCHES_JOINT_SECONDS:-60} + 90)) "$results/launches.out" \
            env JOINT_SECONDS="${LAUNCHES_JOINT_SECONDS:-60}" scripts/kernel-launches.sh \
            "$bin/neurofluid-train" experiments/quick-watercube.toml "$results/launches" \
            --device wgpu
        grep -E '^[a-z]+: [0-9]+ steps' "$results/launches/launches.txt" 2>/dev/null |
            sed 's/^/    /' | tee -a "$summary"
        ;;
    threads)
        timed "CPU time per thread per step, quick main job" \
            $((${THREADS_JOINT_SECONDS:-60} + 120)) "$results/threads.out" \
            python3 scripts/thread-times.py "$bin/neurofluid-train" experiments/quick-watercube.toml \
            "$results/threads" --warmup-iters "${THREADS_WARMUP_ITERS:-60}" \
            --joint-seconds "${THREADS_JOINT_SECONDS:-60}" -- --device wgpu
        sed 's/^/    /' "$results/threads/threads.txt" 2>/dev/null | tee -a "$summary"
        ;;
    profile)
        log=$results/profile.log
        timed "one small PhysNeRF step, cubecl's kernel profile" 60 "$log" \
            env CUBECL_DEBUG_OPTION=profile CUBECL_DEBUG_LOG="$results/profile-kernels.log" \
            "$bin/train_step" --device wgpu
        python3 scripts/cubecl-profile-summary.py "$results/profile-kernels.log" --top 20 | sed 's/^/    /' |
            tee -a "$summary"
        ;;
    dlfprofile)
        log=$results/dlf-profile.log
        timed "DLF steps at 8k, cubecl's kernel profile" 60 "$log" \
            env CUBECL_DEBUG_OPTION=profile CUBECL_DEBUG_LOG="$results/dlf-kernels.log" \
            "$bin/dlf_step" --device wgpu --repeats 1 --sizes 8000
        python3 scripts/cubecl-profile-summary.py "$results/dlf-kernels.log" --top 20 | sed 's/^/    /' |
            tee -a "$summary"
        ;;
    tests)
        # the test binaries the bundle was built with, each with the modules of it to run
        # (none: all of it; gpu-bundle.sh)
        while read -r t modules <&3; do
            [ -n "$t" ] || continue
            # shellcheck disable=SC2086 # the modules are a list of test filters
            NEUROFLUID_TEST_DEVICE=wgpu timed "test $t (${modules:-all})" 600 "$results/tests.log" \
                "$bin/$t" $modules
            [ -x "$bin/$t" ] && grep '^test result' "$results/tests.log" | tail -1 |
                sed 's/^/    /' | tee -a "$summary"
        done 3<"$bundle/tests"
        ;;
    paper)
        timed "paper-scale WaterCube (wgpu, ${PAPER_SECONDS:-300} s at most)" \
            "${PAPER_SECONDS:-300}" "$results/paper.log" "$bin/neurofluid-train" run \
            experiments/paper-watercube.toml --device wgpu --set name=gpu-paper
        ;;
    *) say "unknown step $step (physnerf, physnerf-wgpu, half, search, split, dlf, dlf-wgpu, quick, launches, threads, profile, dlfprofile, tests, paper)" ;;
    esac
done
say "done at $(date -u +%FT%TZ), $SECONDS s"
