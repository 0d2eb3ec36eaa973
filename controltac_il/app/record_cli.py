"""``python -m controltac_il.calibrate record``: calibration presses with the robot you have (``press_record``).

    python -m controltac_il.calibrate record --setup my_ur.yaml --sensor left --start 0.45 0 0.12 0 --out recs
    python -m controltac_il.calibrate record --sim --out recs          # the MuJoCo scene, its pad force known
    python -m controltac_il.calibrate --recordings recs --out my_sensor --lag auto

Exit codes: 0 recorded, 1 a device fault or the force limit (one line; the arm stopped, nothing written), 2 bad
options or a plan refused before moving (one line naming the flag), 130 Ctrl-C (the arm stopped, nothing written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controltac_il.cli import ArgumentParser, RunFault, guard
from controltac_il.io import unwritable

PROG = "python -m controltac_il.calibrate record"
PLAN_FLAGS = ("mode", "presses", "fz_max", "fz_abort", "spread_m", "seed", "fast_step", "slow_step", "max_travel")


def parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog=PROG, description=(
        "Record calibration presses: the arm presses the tactile finger onto a fixed object (--mode press, force "
        "from the wrist F/T of a UR e-series or an xArm) or the gripper squeezes an object (--mode squeeze), along "
        "a force ramp up to --fz-max, through the deployment's control loop and safety limits. Writes one "
        "recording per press (frames + force CSV) for calibrate --recordings."))
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--setup", type=Path, help="the robot's setup YAML (hardware/configs/*.yaml)")
    src.add_argument("--sim", action="store_true", help="the MuJoCo scene: the gripper squeezes the standing peg")
    p.add_argument("--out", type=Path, required=True, help="recordings folder to write (new)")
    p.add_argument("--sensor", default="left", help="the tactile sensor (the setup's tactile name; default left)")
    p.add_argument("--start", type=float, nargs=4, metavar=("X", "Y", "Z", "YAW"),
                   help="robot: the pose (m, rad, base frame) where the finger is just off the object")
    p.add_argument("--mode", choices=("press", "squeeze"), default=None,
                   help="press (robot default) or squeeze (the simulation's; a real gripper reports no force)")
    p.add_argument("--presses", type=int, default=8, help="loading ramps, one recording each (default 8)")
    p.add_argument("--fz-max", type=float, default=9.0, help="N where a ramp turns back, in [2, 10] (default 9)")
    p.add_argument("--fz-abort", type=float, default=12.0, help="N that stops the run, above --fz-max, <= 15 (default 12)")
    p.add_argument("--spread-m", type=float, default=0.003, help="presses start up to this far apart (m, default 0.003)")
    p.add_argument("--seed", type=int, default=0, help="draws the presses' starts (default 0)")
    p.add_argument("--fast-step", type=float, default=None, help="per period: closing fraction or m (default: the mode's)")
    p.add_argument("--slow-step", type=float, default=None, help="per period on the ramp (default: the mode's)")
    p.add_argument("--max-travel", type=float, default=None, help="closing fraction or m in all (default: the mode's)")
    p.add_argument("--tactile-size", type=int, nargs=2, default=None, metavar=("H", "W"),
                   help="--sim: the rendered tactile frames (default 240 320; a robot's size is its setup file's)")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    return guard(PROG, lambda: _run(args), "interrupted (Ctrl-C): the arm was stopped, nothing was written")


def _run(args: argparse.Namespace) -> int:
    from controltac_il.app.press_record import PressPlan, record_presses
    from controltac_il.config import one_line
    from hardware.interfaces import HardwareError

    if args.sim and args.start is not None:
        raise ValueError("--start: a robot's pose; the simulation squeezes the standing peg where it stands")
    if not args.sim and args.tactile_size is not None:
        raise ValueError(f"--tactile-size: the simulation's; a robot's frames have the size {args.setup} gives them")
    args.tactile_size = args.tactile_size or (240, 320)
    mode = args.mode or ("squeeze" if args.sim else "press")
    try:
        plan = PressPlan(**{k: getattr(args, k) for k in PLAN_FLAGS if k != "mode"}, mode=mode)
    except ValueError as exc:
        raise ValueError(one_line(exc, {k: "--" + k.replace("_", "-") for k in PLAN_FLAGS})) from None
    if args.out.exists():
        raise ValueError(f"--out {args.out} exists; recordings are written to a new folder")
    why = unwritable(args.out)
    if why:
        raise ValueError(f"--out {args.out}: {why}")
    from tqdm import tqdm

    with tqdm(total=plan.presses, unit="press", desc="calibration presses", disable=None) as bar:
        def record(*a, **kw):
            return record_presses(*a, **kw, progress=lambda done, total: bar.update(1))

        try:
            summary = (_sim if args.sim else _robot)(args, plan, record)
        except HardwareError as exc:
            raise RunFault(str(exc)) from None
    peaks = summary["peak_fz"]
    print(f"wrote {summary['presses']} presses to {args.out} (peaks {min(peaks):.2f}-{max(peaks):.2f} N, "
          f"force from {summary['force_source']}); next: python -m controltac_il.calibrate --recordings {args.out} "
          f"--out MY_SENSOR --lag auto", file=sys.stderr)
    return 0


def _sim(args, plan, record_presses) -> dict:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    from envs.config import PegInHoleConfig
    from envs.sim_robot import SimRobot

    if plan.mode != "squeeze":
        raise ValueError("--sim: the scene's gels face each other, so its presses are --mode squeeze")
    # the finger servo saturates at the grip force: above the ramp's abort, so the ramp reaches fz_max
    cfg = PegInHoleConfig(cameras=(), tactile_size=tuple(args.tactile_size), grip_force_range_n=(14.0, 14.0))
    with SimRobot(cfg, seed=plan.seed) as robot:
        return record_presses(robot, args.sensor, robot.force.get(args.sensor), plan, robot.squeeze_pose(), args.out)


def _robot(args, plan, record_presses) -> dict:
    from controltac_il.app.press_record import check_plan
    from hardware.config import load_setup, open_setup
    from hardware.ur import URArm, URForce
    from hardware.xarm import XArm, XArmForce

    if plan.mode == "squeeze":
        raise ValueError("--mode squeeze needs the gripper's force, which no supported gripper reports; press with the "
                         "wrist F/T (--mode press), or record with a load cell and use calibrate --recordings")
    if args.start is None:
        raise ValueError("--start X Y Z YAW is required with --setup: the pose where the finger is just off the object")
    cfg = load_setup(args.setup)
    if args.sensor not in cfg.tactile:
        raise ValueError(f"--sensor {args.sensor!r}: {args.setup} names the tactile sensors {sorted(cfg.tactile)}")
    check_plan(plan, cfg.limits, args.start, open_grip=0.0)  # before anything connects (a Robotiq activates)
    with open_setup(cfg) as setup:
        force = {URArm: URForce, XArm: XArmForce}.get(type(setup.arm))
        if force is None:
            raise ValueError(f"{args.setup}: robot.type {cfg.robot.type} has no wrist force reading here")
        with force(setup.arm) as reader:
            return record_presses(setup, args.sensor, reader, plan, args.start, args.out)
