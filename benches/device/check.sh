#!/bin/bash
# One device run (a GPU machine with no Rust toolchain, results under $OUT): the GEMM sweep (bench --gemm-sweep,
# whose recorded choice the rest runs on), GPU parity on the hardware, the benchmark, `register` on the example pair on both backends, and GPU evals of generated sets, each bounded so
# the whole ends within BUDGET seconds (default 440). Prepare with benches/device/pack.sh; run from the
# repository root with `.devbin` and `.gl` carried. Where the machine has no Vulkan loader it unpacks the
# loader's packages into /.
set -u
DEFAULT_BUDGET=440
# shellcheck source=benches/device/setup.sh
source "$(dirname "$0")/setup.sh"
# The GEMM sweep first: it records the fastest GEMM variant and tile for this adapter (in $OUT/gemm_cache,
# which every later command here reads), so the rest runs on it and the file comes back.
export DPR_GPU_CACHE_DIR="$OUT/gemm_cache"
log "gemm sweep"; timeout "$(cap 90)" $bin bench --gemm-sweep --json --peak-tflops "${PEAK_TFLOPS:-67}" \
    > "$OUT/gemm_sweep.json" 2> "$OUT/gemm_sweep.txt"; log "gemm sweep rc=$?"
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
eval_set heldout --style heldout --scenes 4 --fragments 10 --seed 900
eval_set heldout_tof --style heldout-tof --scenes 4 --fragments 10 --seed 950
eval_set valrep --style randomized --scene-kind repeated --scenes 4 --fragments 10 --seed 710
log "end"
