#!/usr/bin/env bash
# One benchmark command on the lent GPU machine, in one call of the device tool, under a deadline:
#
#   bash benchmarks/device_run.sh OUT_DIR DEADLINE_S COMMIT TREE COMMAND...   # carry .whl
#
# e.g. the calibration's held-out-object cases, eight at a time, each fine-tuning on the GPU:
#   bash benchmarks/device_run.sh $OUT 500 C T python3 -m benchmarks.calibration --jobs 8 --threads 2 \
#     --device cuda --heldout-draws 5 --no-sim-record --out $OUT/calibration.json
# COMMIT TREE: as benchmarks/gpu_setup.sh (the JSONs name COMMIT only where the copy's files hash to TREE). The
# command's output goes to OUT_DIR/driver.log; a command that saves as it goes leaves there what finished by the
# deadline, and worker processes still running then are stopped.
set -u
OUT=${1:?OUT_DIR}; DEADLINE=${2:?DEADLINE_S}
mkdir -p "$OUT"
LOG="$OUT/driver.log"
source benchmarks/gpu_setup.sh "$LOG" "${3:?COMMIT}" "${4:?TREE}" || exit $?
echo "commit ${CONTROLTAC_VERIFIED_COMMIT:-not verified}; $(nproc) cores; $(nvidia-smi -L 2>/dev/null | head -1)" >> "$LOG"
# SIGINT, as Ctrl-C: trainers save their state on it (--resume continues); KILL 30 s later if still running
timeout -s INT -k 30 $((DEADLINE - SECONDS - 30)) "${@:5}" 2>&1 | tee -a "$LOG"
echo "exit ${PIPESTATUS[0]} after ${SECONDS} s" >> "$LOG"
pkill -f multiprocessing.spawn  # workers of a command killed at the deadline outlive it
