#!/bin/bash
# One device run (a GPU machine with no Rust toolchain, results under $OUT): GPU parity on the hardware, the
# benchmark, `register` on the example pair on both backends, and GPU evals of generated sets, each bounded so
# the whole ends within BUDGET seconds (default 440). Prepare with benches/device/pack.sh; run from the
# repository root with `.devbin` and `.gl` carried. Where the machine has no Vulkan loader it unpacks the
# loader's packages into /.
set -u
OUT=${OUT:-out/device}; mkdir -p "$OUT"
start=$(date +%s); deadline=$((start + ${BUDGET:-440}))
left() { echo $((deadline - $(date +%s))); }
cap() { local t; t=$(left); [ "$t" -lt 1 ] && t=1; [ "$t" -lt "$1" ] && echo "$t" || echo "$1"; } # seconds, at most $1
log() { echo "[$(($(date +%s) - start))s] $*" | tee -a "$OUT/log.txt"; }
# The Vulkan loader, only where the machine has none (the GPU machines' image has the driver but no loader).
if ! ldconfig -p | grep -q libvulkan.so.1; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg}; mkdir -p "$XDG_RUNTIME_DIR"; chmod 700 "$XDG_RUNTIME_DIR"
(cd .devbin && tar xJf bins.tar.xz) || { log "unpacking .devbin/bins.tar.xz failed"; exit 1; }
bin=.devbin/dpr-gpu
export WGPU_BACKEND=vulkan
probe() { timeout 60 $bin bench --backend gpu --keypoints 64 --points 32 --pair-points 2000 --repeat 1 > /tmp/probe.txt 2>&1; }
if ! probe; then
    log "no adapter by default; trying the NVIDIA driver files"
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    probe || { log "no GPU adapter"; cat /tmp/probe.txt >> "$OUT/log.txt"; exit 1; }
fi
head -3 /tmp/probe.txt >> "$OUT/log.txt"
log "gpu_parity"; CI=true timeout "$(cap 150)" .devbin/gpu_parity > "$OUT/parity.txt" 2>&1; log "gpu_parity rc=$?"
grep -E "FAILED|panicked|test result" "$OUT/parity.txt" >> "$OUT/log.txt"
log "bench"; timeout "$(cap 90)" $bin bench --json --peak-tflops "${PEAK_TFLOPS:-67}" > "$OUT/bench.json"; log "bench rc=$?"
timeout "$(cap 120)" $bin bench --json --peak-tflops "${PEAK_TFLOPS:-67}" --keypoints 5000 --points 256 --pair-points 100000 \
    --repeat 5 > "$OUT/bench_large.json"; log "bench (5,000 keypoints) rc=$?"
for backend in gpu gpu gpu cpu cpu; do
    /usr/bin/time -f "$backend: process wall %e s" timeout "$(cap 60)" \
        $bin register examples/pair/cloud_bin_1.ply examples/pair/cloud_bin_0.ply --backend $backend --json
    echo
done > "$OUT/register.txt" 2>&1
log "register done"
eval_set() { # name synth-args...
    local name=$1; shift
    local t; t=$(left); [ "$t" -lt 30 ] && { log "skipped $name (time)"; return; }
    $bin synth "/tmp/data/$name" "$@" > /dev/null || { log "synth $name failed"; return; }
    t=$(left); log "eval $name (at most ${t}s)"
    timeout "$t" $bin eval "/tmp/data/$name" --backend gpu --keypoints 1000 --estimator both \
        --out "/tmp/eval/$name" > "/tmp/eval/$name.log" 2>&1
    log "eval $name rc=$?"
    grep -E "mean \(|verdict over" "/tmp/eval/$name.log" >> "$OUT/log.txt"
    cp "/tmp/eval/$name/report.json" "$OUT/$name.json" 2>/dev/null
}
mkdir -p /tmp/data /tmp/eval
eval_set heldout --style heldout --scenes 4 --fragments 10 --seed 900
eval_set heldout_tof --style heldout-tof --scenes 4 --fragments 10 --seed 950
eval_set valrep --style randomized --scene-kind repeated --scenes 4 --fragments 10 --seed 710
log "end"
