"""Run a trained ACT policy through the control loop, in the MuJoCo scene or on a robot.

    python deploy_policy.py --robot sim --checkpoint runs/act --episodes 20
    python deploy_policy.py --robot sim --checkpoint runs/act --grip-force 10 12     # shifted grip force
    python deploy_policy.py --robot sim --scene touch_critical --checkpoint runs/touch_act
    python deploy_policy.py --robot xarm --checkpoint runs/act --config setup.yaml

The checkpoint is checked against the set-up (cameras, tactile sensors, action size) before anything
moves; a corrupted or mismatched checkpoint is refused with a clear error. In simulation the success
rate is printed with its Wilson 95 % interval.

Exit status: 0 done; 1 an evaluation episode raised (its seed and error on one line; never counted as a failed
episode, the whole result with every error in --out), or the robot side stopped the run: a device did not answer or failed (one line naming the
setup file and the device), a safety limit or a late policy (the arm was stopped); 2 bad options, setup file
or checkpoint (one line naming the flag, the field or the file); 130 Ctrl-C (the arm was stopped).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from controltac_il.app import EVAL_SEED, SCENES
from controltac_il.cli import ArgumentParser, guard
from controltac_il.io import unwritable

PROG = "deploy_policy.py"
SIM_DEFAULTS = {"episodes": 20, "seed": EVAL_SEED, "scene": "default"}  # --robot sim only


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=("sim", "xarm", "ur"), default="sim", help="where to run (default sim)")
    p.add_argument("--checkpoint", type=Path, required=True,
                   help="checkpoint folder, or a train_act.py --out folder (its best/, else last/)")
    p.add_argument("--config", type=Path, default=None, help="robot set-up YAML (xarm / ur): devices, limits")
    p.add_argument("--episodes", type=int, default=None, help=f"simulated episodes (default {SIM_DEFAULTS['episodes']})")
    p.add_argument("--seed", type=int, default=None, help="first scene seed of the simulated episodes "
                   "(default: the evaluation seeds, disjoint from the demos')")
    p.add_argument("--scene", default=None, choices=SCENES,
                   help="simulated scene: default (pick and insert) or touch_critical (peg held off-centre, "
                        "hidden from the cameras; see PegInHoleConfig.touch_critical)")
    p.add_argument("--grip-force", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="simulated grip force range, N (default: the scene's, 3-9 / 4-7)")
    p.add_argument("--max-steps", type=int, default=None,
                   help="robot: stop after this many control steps (a simulated episode ends at its scene's)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads for inference (default 1: a 20 ms chunk gains little from more, and "
                        "spinning threads slow the simulator down on a busy machine)")
    p.add_argument("--out", type=Path, default=None, help="write the result as JSON to this file")
    return p.parse_args(argv)


def check_args(args: argparse.Namespace) -> None:
    """ValueError (one line naming the flag and the expected form) for an option out of its range, or one the
    chosen robot does not use; fills the simulation's defaults."""
    given = [f for f in (*SIM_DEFAULTS, "grip_force") if getattr(args, f) is not None]
    if args.robot != "sim" and given:
        raise ValueError(f"--{given[0].replace('_', '-')}: a simulated episode's setting, used only with --robot sim")
    if args.robot == "sim" and args.max_steps is not None:
        raise ValueError(f"--max-steps {args.max_steps}: a robot run's length; a simulated episode ends at its scene's")
    for name, default in SIM_DEFAULTS.items():
        setattr(args, name, default if getattr(args, name) is None else getattr(args, name))
    for flag, value in (("--episodes", args.episodes), ("--max-steps", args.max_steps), ("--threads", args.threads)):
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be an integer >= 1, got {value}")
    if args.grip_force is not None:
        low, high = args.grip_force
        if not (0 < low <= high < float("inf")):
            raise ValueError(f"--grip-force LOW HIGH must be finite newtons with 0 < LOW <= HIGH, got {low} {high}")
    if args.robot != "sim" and args.config is None:
        raise ValueError("--config setup.yaml is required with --robot xarm|ur")
    if args.robot == "sim" and args.config is not None:
        raise ValueError(f"--config {args.config}: a robot set-up, used only with --robot xarm|ur (the scene has its own)")
    if args.seed < 0:
        raise ValueError(f"--seed must be an integer >= 0 (the first scene seed), got {args.seed}")
    if args.out is not None:
        where = ("exists: a result never replaces a file" if args.out.exists()
                 else f"its folder {args.out.parent} does not exist or is not a folder" if not args.out.parent.is_dir()
                 else unwritable(args.out))
        if where:
            raise ValueError(f"--out {args.out}: cannot write the result there ({where}); expected a new file path")


def main(argv=None) -> int:
    """0 done; 1 the robot side stopped the run (HardwareError: a device that does not answer or fails, a safety
    violation, a late policy; the arm was stopped) or episodes raised; 2 bad options, setup file, checkpoint or
    output, a missing extra; 130 Ctrl-C. Every failure is one line on stderr."""
    args = parse_args(argv)

    def job() -> int:
        check_args(args)
        from controltac_il.app.deploy import EvaluationError
        from controltac_il.config import one_line
        from hardware.interfaces import HardwareError

        try:
            run(args)
        except EvaluationError as exc:  # a crash inside an episode is not a failed episode: no success rate
            if args.out is not None:
                from controltac_il.io import write_json

                write_json(args.out, exc.result)
            raise
        except HardwareError as exc:  # a device did not answer or failed, a safety limit, a late policy: arm stopped
            print(f"{PROG}: robot error: {one_line(exc)}", file=sys.stderr)
            return 1
        return 0

    return guard(PROG, job, "interrupted (Ctrl-C); the control loop stopped the devices")


def run(args: argparse.Namespace) -> dict:
    """Evaluate in the scene or run on the robot; print (and with --out write) the result."""
    import torch

    from controltac_il.app.deploy import deploy_on_robot, evaluate_in_sim
    from controltac_il.io import write_json

    torch.set_num_threads(max(1, args.threads))
    if args.robot == "sim":
        result = evaluate_in_sim(args.checkpoint, episodes=args.episodes, seed=args.seed,
                                 grip_force_range=args.grip_force, scene=args.scene)
        lo, hi = result["wilson95"]
        print(f"success {result['successes']}/{result['episodes']} = {result['success_rate']:.0%}  "
              f"Wilson 95 % interval [{lo:.0%}, {hi:.0%}]  (grip force {result['grip_force_range_n']} N)")
    else:
        result = deploy_on_robot(args.robot, args.checkpoint, args.config, max_steps=args.max_steps)
        print(json.dumps(result, indent=2))
    if args.out is not None:
        write_json(args.out, result)
    return result

