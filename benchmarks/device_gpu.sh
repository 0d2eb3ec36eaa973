#!/usr/bin/env bash
# The generator's device figures in one call of the device tool, each stage under what is left of a deadline:
#
#   bash benchmarks/device_gpu.sh OUT_DIR [DEADLINE_S] [COMMIT TREE]   # carry .whl .baseline; COMMIT TREE from
#       `git rev-parse --short HEAD HEAD^{tree}` here: the device's copy of .git is stale, so the JSONs name COMMIT
#       only where the copy's files hash to TREE (CONTROLTAC_VERIFIED_COMMIT, benchmarks.common), else its describe
#
# 1. generator_speed_gpu.json: every shipped size (the presets and the frontier's) at 240×320 and 120×160, DDIM-1,
#    float32, batch 32, 256 and auto, its error (MSE ÷ a copy's on the unseen-object pairs) beside each speed;
# 2. generator_speed_gpu_dtypes.json: the same at batch auto in bfloat16 and float16 (their speed and error);
# 3. generator_cpu_change.json, from the start on cores 8-11 beside the GPU stages (on 0-7): the CPU path of fast and
#    default on 2 threads, this tree against the code in .baseline (benchmarks.generator_cpu_change: speed
#    interleaved, output bytes compared).
# A stage that would start with under 40 s left is skipped and said so in OUT_DIR/driver.log, which comes back with
# the JSONs. Wheels the GPU machine lacks come from .whl (benchmarks/gpu_setup.sh). DEVICE_SMOKE=1: the same on the
# CPU, tiny (checks this script before a device call).
set -u
OUT=${1:?OUT_DIR}; DEADLINE=${2:-480}
DEVICE=cuda; SPEED="--rounds 3 --repeats 3"; CHANGE="--rounds 3 --repeats 3 --checkpoints fast default"; PAIRS=96
SPEED_CORES=0-7; CHANGE_CORES=8-11
if [ "${DEVICE_SMOKE:-0}" = 1 ]; then
  DEVICE=cpu; SPEED="--quick --threads 1"; CHANGE="--rounds 1 --repeats 1 --checkpoints fast"; PAIRS=4
  SPEED_CORES=0; CHANGE_CORES=1
fi
mkdir -p "$OUT"
LOG="$OUT/driver.log"
log() { echo "[$(date -u +%T) +${SECONDS}s] $*" | tee -a "$LOG"; }
if [ "$DEVICE" = cpu ]; then export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"; else source benchmarks/gpu_setup.sh "$LOG" "${3:-}" "${4:-}" || exit $?; fi
log "commit ${CONTROLTAC_VERIFIED_COMMIT:-not verified}; $(nproc) cores; $(nvidia-smi -L 2>/dev/null | head -1)"
stage() {  # stage NAME COMMAND...: run it under what is left of the deadline
  local left=$((DEADLINE - SECONDS))
  if [ "$left" -lt 40 ]; then log "$1: skipped, ${left} s left"; return; fi
  log "$1: started, ${left} s left"
  timeout "$left" "${@:2}" >> "$LOG" 2>&1 && log "$1: done" || log "$1: failed or timed out (exit $?)"
}
# the CPU comparison on cores of its own, beside the GPU stages (which use the GPU and one core)
stage cpu_change taskset -c $CHANGE_CORES python3 -m benchmarks.generator_cpu_change --baseline .baseline \
  --threads ${CPU_THREADS:-2} $CHANGE --out "$OUT/generator_cpu_change.json" &
stage speed taskset -c $SPEED_CORES python3 -m benchmarks.generator_speed --device $DEVICE --steps 1 \
  --batch-sizes 32 256 auto --pairs $PAIRS $SPEED --out "$OUT/generator_speed_gpu.json"
stage dtypes taskset -c $SPEED_CORES python3 -m benchmarks.generator_speed --device $DEVICE --checkpoints fast default quality \
  --steps 1 --batch-sizes auto --dtypes bfloat16 float16 --pairs $PAIRS $SPEED --out "$OUT/generator_speed_gpu_dtypes.json"
wait
log "finished: $(ls "$OUT" | tr '\n' ' ')"
