#!/bin/bash
# One training run on a GPU machine with no Rust toolchain (results under $OUT), within BUDGET seconds (default
# 560): the training kernels' parity tests first, then the data of the orbit run (docs/experiments/orbit.md) generated there
# (TRAIN_SCENES scenes of its five sets, default "12 20 16 16 8": kinect seed 1, randomized seed 2, randomized
# repeated-kind seed 4, randomized rooms with --orbit seed 6, repeated-kind with --orbit seed 7), the default
# weights continued on the device with that run's settings plus half the patches cut on the PPF branch only and
# a slower decay (docs/experiments/slow-decay.md; `train --backend gpu`, --max-seconds up to
# EVAL_RESERVE seconds before the end, default 200; BATCH pairs a step, default 32; LR_DECAY_EVERY steps per
# halving of the learning rate, default 2500: stretch it with a longer run),
# and GPU evals of the result: the repetition tuning set (seed 710, never trained on) and the held-out halls
# (seed 900; reported, never chosen on), EVAL_SCENES scenes each (default 4). Back in $OUT: the weights
# (gpu-run.safetensors), the loss log, the training log, the parity tests' output, the bench (its train_step
# stage: a step's cost at the recipe's size), the evals' reports and log.txt. Prepare with
# benches/device/pack.sh; run from the repository root with `.devbin` and `.gl` carried.
set -u
DEFAULT_BUDGET=560
# shellcheck source=benches/device/setup.sh
source "$(dirname "$0")/setup.sh"
if [ -z "${BIN:-}" ]; then # the training kernels' parity on this device first (seconds); the run goes on anyway
    CI=true timeout "$(cap 90)" .devbin/gpu_parity relu_backward group_row_sums max_pool_backward dense_weight_grad \
        dense_input_grad backward adam_step tape chamfer transpose device_objective device_step device_training \
        > "$OUT/parity.txt" 2>&1
    log "training parity rc=$?"; grep -E "FAILED|panicked|test result" "$OUT/parity.txt" >> "$OUT/log.txt"
fi
# The step's cost in steady state at the recipe's size (`train_step`: 32 pairs x 256 points), CPU beside it.
timeout "$(cap 90)" $bin bench --json --keypoints 64 --points 256 --pair-points 0 > "$OUT/bench_train.json"
log "bench (train_step) rc=$?"
read -r kinect random repeated orbit orbitrep <<< "${TRAIN_SCENES:-12 20 16 16 8}"
data=/tmp/data/train
mkdir -p "$data" /tmp/run
log "synth training data ($kinect + $random + $repeated + $orbit + $orbitrep scenes)"
$bin synth "$data/kinect" --scenes "$kinect" --fragments 10 --seed 1 > /dev/null &
$bin synth "$data/random" --style randomized --scenes "$random" --fragments 10 --seed 2 > /dev/null &
$bin synth "$data/repeated" --style randomized --scene-kind repeated --scenes "$repeated" --fragments 10 --seed 4 \
    > /dev/null &
$bin synth "$data/orbit" --style randomized --scene-kind room --orbit --scenes "$orbit" --fragments 10 --seed 6 \
    > /dev/null &
$bin synth "$data/orbitrep" --style randomized --scene-kind repeated --orbit --scenes "$orbitrep" --fragments 10 \
    --seed 7 > /dev/null &
wait
secs=$(($(left) - ${EVAL_RESERVE:-200}))
[ "$secs" -lt 30 ] && { log "too little time left to train (${secs}s)"; exit 1; }
log "train for ${secs}s (data preparation included)"
# The limit stops the run and saves it; the timeout is a backstop 30 s later.
timeout "$((secs + 30))" $bin train --data "$data/kinect" "$data/random" "$data/repeated" "$data/orbit" \
    "$data/orbitrep" --out "$OUT/gpu-run.safetensors" --init weights/default.safetensors --backend gpu \
    --steps 1000000 --max-seconds "$secs" --lr-decay-every "${LR_DECAY_EVERY:-2500}" --batch "${BATCH:-32}" \
    --lr 3e-4 --seed 35 --lambda-contrast 1 --contrast-margin 0.5 --patches-per-pair 4 --wide-view-share 0.3 \
    --wide-view-deg 60 --occlusion-share 0.5 --occlusion-deg 30,120 --occlusion-ppf-only \
    --checkpoint-every 200 --checkpoint /tmp/run/gpu.ckpt.safetensors \
    --log "$OUT/losses.csv" > "$OUT/train.log" 2>&1
log "train rc=$?"
tail -n 2 "$OUT/train.log" >> "$OUT/log.txt"
if [ -s "$OUT/gpu-run.safetensors" ]; then
    export EVAL_WEIGHTS="$OUT/gpu-run.safetensors"
    scenes=${EVAL_SCENES:-4}
    eval_set valrep --style randomized --scene-kind repeated --scenes "$scenes" --fragments 10 --seed 710
    eval_set heldout --style heldout --scenes "$scenes" --fragments 10 --seed 900
fi
log "end"
