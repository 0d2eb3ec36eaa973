#!/usr/bin/env bash
# The frontier's model sizes trained side by side on one GPU, in one call of the device tool.
#
#   bash benchmarks/frontier_gpu.sh OUT_DIR [STEPS] [DEADLINE_S]       # the device call: `... $OUT 8000 440 2>&1`
#
# (No `| tail` in the device call: a command stopped at its limit loses a pipeline's output; the tool returns the
# last 12 000 characters anyway.) The committed run: STEPS 8000 took 565 s to the last checkpoint on an H200
# (40 s render, 90 s reading and encoding, 296 / 327 / 424 s of DiT steps side by side; its deadline never
# fired, the Ctrl-C of a script without job control not reaching background jobs): the default deadline, 570 s,
# leaves it room, and the speed benchmark runs only where time is left, else in a call of its own.
#
# Renders proc240v (the shipped default's last-stage data, docs/generator.md) with 15 processes, trains the DiT
# presets tiny, small and base at patch 4 from scratch under one protocol (the shipped default's autoencoder,
# the same data, flags, steps and seed, each its own best-on-validation step over 10 held-out objects) side by
# side on the GPU, then times every checkpoint on the GPU (benchmarks.generator_speed). A training still running
# DEADLINE_S seconds after the start gets Ctrl-C (its state is saved; its best-on-validation weights come back).
# OUT_DIR gets <size>.tgz (the final checkpoint, or the best weights in fp16 where stopped), speed_gpu.json and
# logs.tgz; archives over 15 MB are split (<name>.part-aa, -ab, ...), as the device tool returns files of 16 MiB.
# Wheels missing on the GPU machine (diffusers, pydantic, ...) are installed from .whl/ (benchmarks/gpu_setup.sh).
# FRONTIER_SMOKE=1: the same on the CPU with a small dataset (checks this script before a device call).
set -um  # -m: job control, so that the trainings started in the background take the deadline's Ctrl-C (SIGINT)
OUT=${1:?OUT_DIR}; STEPS=${2:-8000}; DEADLINE=${3:-570}
RENDER="--procedural 114 --poses-per-object 30 --workers 15"; DEVICE=cuda; VAL=10; EVERY=500
if [ "${FRONTIER_SMOKE:-0}" = 1 ]; then RENDER="--procedural 10 --poses-per-object 3 --workers 2"; DEVICE=cpu; VAL=3; EVERY=5; fi
RUNS=/tmp/frontier; DATA=/tmp/frontier_data/proc240v
rm -rf "$RUNS" "$(dirname "$DATA")"  # a warm machine keeps the last call's /tmp: start clean
mkdir -p "$OUT" "$RUNS" "$(dirname "$DATA")"
log() { echo "[$(date -u +%T) +${SECONDS}s] $*" | tee -a "$RUNS/driver.log"; }
log "commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown); $(nproc) cores; $(nvidia-smi -L 2>/dev/null | head -1)"
if [ "$DEVICE" = cpu ]; then export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"; else source benchmarks/gpu_setup.sh "$RUNS/driver.log" || exit $?; fi

log "rendering proc240v"
python3 -m controltac_il.tactile.dataset --size 240 320 --out "$DATA" $RENDER \
  --forces-per-pose 8 --seed 5 --sensors train --instances 24 >> "$RUNS/driver.log" 2>&1 || { log "render failed"; tar czf "$OUT/logs.tgz" -C "$RUNS" .; exit 4; }
log "rendered"

FLAGS="--data $DATA --stage denoiser --autoencoder-from default --dit-patch 4 --dit-conv-head 48 --prediction-type sample
  --default-steps 1 --dit-steps $STEPS --dit-batch 128 --dit-lr 5e-4 --one-step-fraction 0.9 --warmup-steps 200
  --distinct-pairs --anchor-to-reference --detail-gate 4 --val-objects $VAL --checkpoint-every $EVERY --seed 5 --device $DEVICE"
for size in tiny small base; do
  python3 -m controltac_il.generator.training stage1 $FLAGS --dit-preset "$size" --out "$RUNS/$size" > "$RUNS/$size.log" 2>&1 &
  echo $! > "$RUNS/$size.pid"
done
running() { for size in tiny small base; do kill -0 "$(cat "$RUNS/$size.pid")" 2>/dev/null && return 0; done; return 1; }
while [ "$SECONDS" -lt "$DEADLINE" ] && running; do sleep 5; done
for size in tiny small base; do
  pid=$(cat "$RUNS/$size.pid")
  kill -0 "$pid" 2>/dev/null && kill -INT "$pid" && log "$size: Ctrl-C at the deadline (its state is saved at the step in hand)"
done
wait
log "trainings ended"

CKPTS=""
for size in tiny small base; do
  if [ -f "$RUNS/$size/final/config.json" ]; then CKPTS="$CKPTS $RUNS/$size/final"; fi
done
left=$((580 - SECONDS))  # the device tool's 600 s per call, packing included
if [ "$left" -gt 30 ]; then
  timeout "$left" python3 -m benchmarks.generator_speed --device $DEVICE --checkpoints fast default $CKPTS \
    --out "$OUT/speed_gpu.json" >> "$RUNS/driver.log" 2>&1 || log "speed benchmark failed or timed out"
else log "no time left for the speed benchmark: time the checkpoints in a call of their own"; fi

for size in tiny small base; do
  r="$RUNS/$size"
  [ -f "$r/denoiser_state.json" ] || continue
  if [ ! -f "$r/final/config.json" ] && [ -f "$r/denoiser_best.safetensors" ]; then  # stopped: best weights, fp16
    python3 -c "import sys, torch; from safetensors.torch import load_file, save_file; \
save_file({k: v.half() for k, v in load_file(sys.argv[1]).items()}, sys.argv[2])" \
      "$r/denoiser_best.safetensors" "$r/best_fp16.safetensors"
  fi
  (cd "$r" && tar czf "$OUT/$size.tgz" train_config.json denoiser_state.json $(ls -d final best_fp16.safetensors 2>/dev/null))
  if [ "$(stat -c %s "$OUT/$size.tgz")" -gt 15000000 ]; then
    split -b 15000000 "$OUT/$size.tgz" "$OUT/$size.tgz.part-" && rm "$OUT/$size.tgz"
  fi
done
log "packed: $(ls "$OUT" | tr '\n' ' ')"
tar czf "$OUT/logs.tgz" -C "$RUNS" $(cd "$RUNS" && ls *.log)
