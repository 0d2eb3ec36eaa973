"""The main job on the embedded default: ``python -m controltac_il`` (what ``./run.sh`` runs).

Renders a contact sheet of the sensor model (every object at 1, 3, 6, 10 N), then runs the whole
pipeline in the MuJoCo scene: collect scripted demos → ForceAugment (shipped generator) → train ACT
with the cpu preset → deploy through the robot's control loop → success rate with its Wilson 95 %
interval and the time per stage. Outputs go to ``--out`` (default ./out).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, TactileSensor
from controltac_il.tactile.sheet import contact_sheet, save_png

FORCES = (1.0, 3.0, 6.0, 10.0)


def main(argv=None) -> None:
    from controltac_il.pipeline import PipelineConfig, run_pipeline

    d = PipelineConfig()
    p = argparse.ArgumentParser(prog="python -m controltac_il", description=__doc__.split("\n\n")[1],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("out"), help="folder for the job's outputs")
    p.add_argument("--demos", type=int, default=d.demos, help="scripted demos collected in the scene")
    p.add_argument("--copies", type=int, default=d.copies, help="ForceAugment copies per demo (0 = real only)")
    p.add_argument("--steps", type=int, default=d.steps, help="ACT training steps (cpu preset)")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes, help="seeded deployment episodes")
    p.add_argument("--sensor-only", action="store_true", help="only render the contact sheet")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    objects = TRAIN_OBJECTS + HELDOUT_OBJECTS
    path = save_png(args.out / "contact_sheet.png", contact_sheet(TactileSensor(), objects, FORCES)[::2, ::2])
    print(f"[sensor] contact sheet, {len(objects)} objects × forces {FORCES} N: {path} "
          f"({time.perf_counter() - t0:.1f} s)")
    if args.sensor_only:
        return
    config = PipelineConfig(demos=args.demos, copies=args.copies, steps=args.steps, eval_episodes=args.eval_episodes)
    run_pipeline(args.out / "pipeline", config)


if __name__ == "__main__":
    main()
