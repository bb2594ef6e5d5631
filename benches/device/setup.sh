#!/bin/bash
# Sourced by the device scripts (check.sh, train.sh) on a GPU machine with no Rust toolchain: $OUT, a deadline
# BUDGET seconds from now (default: the caller's DEFAULT_BUDGET) with `left`, `cap` and `log`, the Vulkan loader
# where the machine has none, the binaries packed by pack.sh unpacked into .devbin, and a probe that finds the
# GPU adapter (trying the NVIDIA driver files where the default search finds none). Exits when there is none.
# `eval_set NAME SYNTH-ARGS...` generates a set and evaluates it on the GPU (with EVAL_WEIGHTS when set).
OUT=${OUT:-out/device}; mkdir -p "$OUT"
start=$(date +%s); deadline=$((start + ${BUDGET:-${DEFAULT_BUDGET:-440}}))
left() { echo $((deadline - $(date +%s))); }
cap() { local t; t=$(left); [ "$t" -lt 1 ] && t=1; [ "$t" -lt "$1" ] && echo "$t" || echo "$1"; } # seconds, at most $1
log() { echo "[$(($(date +%s) - start))s] $*" | tee -a "$OUT/log.txt"; }
# The Vulkan loader, only where the machine has none (the GPU machines' image has the driver but no loader).
if ! ldconfig -p | grep -q libvulkan.so.1; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg}; mkdir -p "$XDG_RUNTIME_DIR"; chmod 700 "$XDG_RUNTIME_DIR"
if [ -n "${BIN:-}" ]; then
    bin=$BIN # a dry run of the scripts' control flow on another machine (e.g. lavapipe): a local build
else
    (cd .devbin && tar xJf bins.tar.xz) || { log "unpacking .devbin/bins.tar.xz failed"; exit 1; }
    bin=.devbin/dpr-gpu
fi
export WGPU_BACKEND=vulkan
probe() { timeout 60 $bin bench --backend gpu --keypoints 64 --points 32 --pair-points 2000 --repeat 1 > /tmp/probe.txt 2>&1; }
if [ -n "${BIN:-}" ]; then
    log "dry run with $bin: no probe" # lavapipe needs minutes for the probe; the scripts' steps say if it fails
elif ! probe; then
    log "no adapter by default; trying the NVIDIA driver files"
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    probe || { log "no GPU adapter"; cat /tmp/probe.txt >> "$OUT/log.txt"; exit 1; }
fi
[ -z "${BIN:-}" ] && head -3 /tmp/probe.txt >> "$OUT/log.txt"
eval_set() { # name synth-args...
    local name=$1; shift
    local t; t=$(left); [ "$t" -lt 30 ] && { log "skipped $name (time)"; return; }
    mkdir -p /tmp/data /tmp/eval
    $bin synth "/tmp/data/$name" "$@" > /dev/null || { log "synth $name failed"; return; }
    t=$(left); log "eval $name (at most ${t}s)"
    timeout "$t" $bin eval "/tmp/data/$name" --backend gpu --keypoints 1000 --estimator both \
        ${EVAL_WEIGHTS:+--weights "$EVAL_WEIGHTS"} --out "/tmp/eval/$name" > "/tmp/eval/$name.log" 2>&1
    log "eval $name rc=$?"
    grep -E "mean \(|verdict over" "/tmp/eval/$name.log" >> "$OUT/log.txt"
    cp "/tmp/eval/$name/report.json" "$OUT/$name.json" 2>/dev/null
}
