#!/usr/bin/env bash
# benchmarks.calibration on the lent GPU machine in one call of the device tool (its 16 cores, eight sensor cases at
# a time, each fine-tuning the generator on the GPU):
#
#   bash benchmarks/device_calibration.sh OUT_DIR [DEADLINE_S] [DRAWS] [COMMIT TREE]   # carry .whl
#
# OUT_DIR/calibration.json holds every case finished by the deadline (saved as each finishes: `--resume` with it
# continues); the MuJoCo scene's presses are left to a machine with MuJoCo (`--resume` there adds them).
# COMMIT TREE: as benchmarks/gpu_setup.sh. DEVICE_SMOKE=1: the same on the CPU, tiny (checks this script first).
set -u
OUT=${1:?OUT_DIR}; DEADLINE=${2:-480}; DRAWS=${3:-5}
mkdir -p "$OUT"
LOG="$OUT/driver.log"
if [ "${DEVICE_SMOKE:-0}" = 1 ]; then
  export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"; RUN="--quick --jobs 2 --threads 1 --device cpu"
else
  source benchmarks/gpu_setup.sh "$LOG" "${4:-}" "${5:-}" || exit $?; RUN="--jobs 8 --threads 2 --device cuda"
fi
echo "commit ${CONTROLTAC_VERIFIED_COMMIT:-not verified}; $(nproc) cores; $(nvidia-smi -L 2>/dev/null | head -1)" >> "$LOG"
timeout $((DEADLINE - SECONDS)) python3 -m benchmarks.calibration $RUN --heldout-draws "$DRAWS" \
  --no-sim-record --out "$OUT/calibration.json" 2>&1 | tee -a "$LOG"
echo "exit ${PIPESTATUS[0]} after ${SECONDS} s" >> "$LOG"
pkill -f multiprocessing.spawn  # a case still running at the deadline: its worker outlives the killed parent
