"""The main job on the embedded default: ``python -m controltac_il`` (what ``./run.sh`` runs).

Renders a contact sheet of the sensor model, then runs the whole pipeline in the MuJoCo scene:
collect scripted demos → ForceAugment (shipped generator) → train ACT with the cpu preset → deploy
through the robot's control loop → success rate with its Wilson 95 % interval and the time per stage.
Outputs go to ``--out`` (default ./out).

Exit status (the training CLIs', ``controltac_il.training.run_cli``): 0 done; 1 training stopped on a NaN / inf
loss; 2 bad options, data or output folder (one line on stderr naming the flag or the file); 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controltac_il.cli import ArgumentParser

PROG = "python -m controltac_il"
FLAGS = {"demos": "--demos", "copies": "--copies", "steps": "--steps", "eval_episodes": "--eval-episodes"}


def parse_args(argv=None) -> argparse.Namespace:
    from controltac_il.app.job_config import PipelineConfig

    d = PipelineConfig()
    p = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[1],
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("out"), help="folder for the job's outputs")
    p.add_argument("--demos", type=int, default=d.demos, help="scripted demos collected in the scene")
    p.add_argument("--copies", type=int, default=d.copies, help="ForceAugment copies per demo (0 = real only)")
    p.add_argument("--steps", type=int, default=d.steps, help="ACT training steps (cpu preset)")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes, help="seeded deployment episodes")
    p.add_argument("--sensor-only", action="store_true", help="only render the contact sheet")
    return p.parse_args(argv)


OUTPUTS = ("contact_sheet.png", "pipeline")  # what the job writes in --out; a run replaces its own


def main(argv=None) -> int:
    """Run the job; returns the exit status (every failure one line on stderr)."""
    args = parse_args(argv)  # before the job's imports (torch, MuJoCo): --help answers at once
    from controltac_il.app.job_config import PipelineConfig
    from controltac_il.config import one_line
    from controltac_il.training import run_cli

    try:
        config = PipelineConfig(demos=args.demos, copies=args.copies, steps=args.steps,
                                eval_episodes=args.eval_episodes)
    except ValueError as exc:  # pydantic: one line naming the flag
        print(f"{PROG}: error: {one_line(exc, FLAGS)}", file=sys.stderr)
        return 2

    def job() -> None:
        from controltac_il.app.job import render_contact_sheet, run_pipeline  # MuJoCo: a missing [sim] is one line

        foreign = sorted(p.name for p in args.out.iterdir() if p.name not in OUTPUTS) if args.out.is_dir() else []
        if foreign:
            raise ValueError(f"--out {args.out} holds files this job did not write ({', '.join(foreign[:3])}); "
                             "nothing was changed: choose another --out")
        args.out.mkdir(parents=True, exist_ok=True)
        render_contact_sheet(args.out)
        if not args.sensor_only:
            run_pipeline(args.out / "pipeline", config)

    return run_cli(PROG, job)


if __name__ == "__main__":
    sys.exit(main())
