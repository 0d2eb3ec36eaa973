"""The main job on the embedded default: ``python -m controltac_il`` (what ``./run.sh`` runs).

Renders a contact sheet of the sensor model, then runs the whole pipeline in the MuJoCo scene:
collect scripted demos → ForceAugment (shipped generator) → train ACT with the cpu preset → deploy
through the robot's control loop → success rate with its Wilson 95 % interval and the time per stage.
Outputs go to ``--out`` (default ./out).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main(argv=None) -> None:
    from controltac_il.app.job import PipelineConfig, render_contact_sheet, run_pipeline

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
    render_contact_sheet(args.out)
    if not args.sensor_only:
        run_pipeline(args.out / "pipeline", PipelineConfig(demos=args.demos, copies=args.copies, steps=args.steps,
                                                          eval_episodes=args.eval_episodes))


if __name__ == "__main__":
    main()
