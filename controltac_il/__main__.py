"""The main job on the embedded default: ``python -m controltac_il`` (what ``./run.sh`` runs).

Stage 1 (sensor model): render a contact sheet of synthetic GelSight Mini images of every object at
several forces and run the sensor benchmark (quick). Later stages (collect demos in the MuJoCo scene,
ForceAugment, ACT training, deployment) run when their modules are installed.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, TactileSensor
from controltac_il.tactile.sheet import contact_sheet, save_png

FORCES = (1.0, 3.0, 6.0, 10.0)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m controltac_il", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("out"), help="folder for the job's outputs (default: ./out)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    sensor = TactileSensor()
    sheet = contact_sheet(sensor, TRAIN_OBJECTS + HELDOUT_OBJECTS, FORCES)
    path = save_png(args.out / "contact_sheet.png", sheet[::2, ::2])
    print(f"[sensor] contact sheet of {len(TRAIN_OBJECTS + HELDOUT_OBJECTS)} objects × {len(FORCES)} forces "
          f"{FORCES} N: {path} ({time.perf_counter() - t0:.1f} s)")

    from benchmarks import sensor as sensor_benchmark

    sensor_benchmark.main(["--quick", "--out", str(args.out / "sensor_benchmark.json")])


if __name__ == "__main__":
    main()
