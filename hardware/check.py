"""Check a setup file, and optionally the devices it names, without moving the arm.

    python -m hardware.check hardware/configs/xarm7_gelsight.yaml            # validate the file
    python -m hardware.check my_setup.yaml --connect --seconds 3             # connect, read, report

With --connect: connects the arm and gripper, starts every camera and GelSight (capturing the
backgrounds, so keep the gels untouched), then prints the arm pose, the gripper position and each
sensor's frame rate and newest-frame age; the arm is stopped and everything closed at the end. The arm is
never commanded, but connecting a gripper may move it: a Robotiq activates (its fingers open and close once) and a
Dynamixel's torque is switched off and on; either drops what it holds, so empty the gripper first.

Exit status: 0 valid (and, with --connect, every device answered); 2 the file is invalid (one line on
stderr naming the file, the field and the expected form: fix the file); 1 a device could not be reached or
failed while being read (one line naming the setup file and the device's address or port: fix the
cabling, the power or the network, then run it again); 130 Ctrl-C (the devices closed).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from tqdm import tqdm

from controltac_il.cli import ArgumentParser, RunFault, guard
from controltac_il.config import one_line
from controltac_il.extras import MissingExtra
from controltac_il.streams import LOOP, image_key, tactile_key
from hardware.config import ConfigError, load_setup, open_setup
from hardware.interfaces import HardwareError


PROG = "python -m hardware.check"


def main(argv=None) -> int:
    p = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("config", help="setup YAML file (see hardware/configs/)")
    p.add_argument("--connect", action="store_true", help="also connect the devices and read them (the arm is never commanded; connecting a "
                        "Robotiq or Dynamixel gripper may move it: empty it first)")
    p.add_argument("--seconds", type=float, default=2.0, help="how long to watch the sensors with --connect (s)")
    args = p.parse_args(argv)
    if not 0 <= args.seconds < float("inf"):  # 0: read each device once
        p.error(f"--seconds: expected a finite duration >= 0 s, got {args.seconds}")
    return guard(PROG, lambda: _check(args), interrupted="device check interrupted (Ctrl-C); the devices were closed")


def _check(args) -> None:
    """Validate the setup file and, with --connect, read its devices. ValueError (exit 2) for the file, a missing
    SDK or a bad device path; RunFault (exit 1) for a device that cannot be reached or fails while read."""
    try:
        cfg = load_setup(args.config)
    except ConfigError as exc:
        raise ValueError(f"invalid setup: {one_line(exc)}") from None
    print(f"{args.config}: valid setup {cfg.name!r}: robot {cfg.robot.type}, gripper {cfg.gripper.type}, "
          f"cameras {sorted(cfg.cameras)}, tactile {sorted(cfg.tactile)}, {cfg.control.rate_hz} Hz")
    if not args.connect:
        return
    try:
        _connect_and_report(cfg, args.seconds)
    except ConfigError as exc:  # validated again before anything connects
        raise ValueError(f"invalid setup: {one_line(exc)}") from None
    except HardwareError as exc:  # open_setup names the file for a device it cannot reach; later faults get it here
        msg = one_line(exc)
        raise RunFault(f"device check failed: {msg if msg.startswith(str(args.config)) else f'{args.config}: {msg}'}") from None
    except (MissingExtra, ValueError, OSError) as exc:  # an SDK not installed (the extra to install), a bad value
        raise ValueError(f"device check failed: {one_line(exc)}") from None  # or device path the setup names


def _connect_and_report(cfg, seconds: float) -> None:
    with open_setup(cfg) as setup:
        print(f"arm pose [x, y, z, yaw]: {np.round(setup.arm.state().pose, 4).tolist()}")
        if setup.gripper is not None:
            print(f"gripper closing: {setup.gripper.state().position:.3f}")
        sources = {**{image_key(k, LOOP): v for k, v in setup.cameras.items()},
                   **{tactile_key(k, LOOP): v for k, v in setup.tactile.items()}}
        first, clock = {k: s.latest() for k, s in sources.items()}, setup.clock  # the frames' own time base
        end = clock.now() + seconds
        with tqdm(total=seconds, desc="watching sensors", unit="s", disable=None) as bar:
            while (left := end - clock.now()) > 0:
                clock.sleep_until(clock.now() + min(0.1, left))
                bar.n = round(seconds - max(left, 0), 1)
                bar.refresh()
        for k, s in sources.items():
            last = s.latest()
            fps = (last.index - first[k].index) / max(last.timestamp - first[k].timestamp, 1e-9)
            age = clock.now() - last.timestamp
            print(f"{k}: {last.image.shape[1]}x{last.image.shape[0]} at {fps:.1f} fps, newest frame {age * 1e3:.0f} ms old")


if __name__ == "__main__":
    sys.exit(main())
