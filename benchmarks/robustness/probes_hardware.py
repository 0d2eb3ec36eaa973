"""Probes of the robot setup file: ``python -m hardware.check`` must refuse every implausible setup."""

from __future__ import annotations

import time

from benchmarks.robustness.harness import CLEAR, judge_cli, probe, run_cli, setup_yaml


def _check(tmp, edit=None, text=None, *names):
    return judge_cli(run_cli(["-m", "hardware.check", str(setup_yaml(tmp, edit, text))], timeout=60), *names)


def _limits(**kw):
    return lambda c: c["limits"].update(kw)


CASES = [  # (probe name, edit of the valid setup, words the error must name)
    ("max_step_m: 5.0 per period", _limits(max_step_m=5.0), ("max_step_m",)),
    ("max_rotation_rad: 100 per period", _limits(max_rotation_rad=100), ("max_rotation_rad",)),
    ("a ±100 m workspace", _limits(workspace_min=[-100, -100, 0.02], workspace_max=[100, 100, 0.4]), ("workspace",)),
    ("a workspace below the base (negative z)", _limits(workspace_min=[0.25, -0.25, -0.5]), ("workspace_min",)),
    ("workspace_min above workspace_max", _limits(workspace_min=[0.7, -0.25, 0.02]), ("workspace",)),
    ("no limits: section", lambda c: c.pop("limits"), ("limits",)),
    ("NaN in tool_rpy", lambda c: c["robot"].update(tool_rpy=[float("nan"), 0.0]), ("tool_rpy",)),
    ("ip 'not an ip'", lambda c: c["robot"].update(ip="not an ip"), ("ip",)),
    ("unknown robot type", lambda c: c["robot"].update(type="kuka"), ("type",)),
    ("camera fps -30", lambda c: c["cameras"]["third_view"].update(fps=-30), ("fps",)),
    ("camera size 0 x 0", lambda c: c["cameras"]["third_view"].update(size=[0, 0]), ("size",)),
    ("control rate 10 000 Hz", lambda c: c["control"].update(rate_hz=10000), ("rate_hz",)),
    ("control rate 0 Hz", lambda c: c["control"].update(rate_hz=0), ("rate_hz",)),
    ("stream_hz -100", lambda c: c["robot"].update(stream_hz=-100), ("stream_hz",)),
    ("xArm gripper open == closed", lambda c: c["gripper"].update(open_position=400, closed_position=400),
     ("position",)),
    ("Robotiq force 1000", lambda c: c.update(gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "force": 1000}),
     ("force",)),
    ("Robotiq speed -5", lambda c: c.update(gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "speed": -5}),
     ("speed",)),
    ("Dynamixel open == closed", lambda c: c.update(gripper={
        "type": "dynamixel", "port": "/dev/ttyUSB0", "dxl_id": 1, "open_position": 2048, "closed_position": 2048}),
     ("position",)),
    ("Dynamixel id 300", lambda c: c.update(gripper={
        "type": "dynamixel", "port": "/dev/ttyUSB0", "dxl_id": 300, "open_position": 2048, "closed_position": 3100}),
     ("dxl_id",)),
    ("an unknown field (typo)", lambda c: c["limits"].update(max_stp_m=0.02), ("max_stp_m",)),
    ("a boolean given as a string", lambda c: c["control"].update(inference="yes please"), ("inference",)),
]

for _name, _edit, _names in CASES:
    probe("hardware.check", _name)(lambda tmp, e=_edit, n=_names: _check(tmp, e, None, *n))


@probe("hardware.check", "a duplicated YAML key")
def _(tmp):
    text = setup_yaml(tmp).read_text().replace("control:\n", "control:\n  rate_hz: 500\n", 1)
    return _check(tmp, None, text, "rate_hz")


@probe("hardware.check", "a YAML syntax error")
def _(tmp):
    return _check(tmp, None, "robot: {type: xarm, ip: [192.0.2.1\n", "setup.yaml")


@probe("hardware.check", "a setup file that does not exist")
def _(tmp):
    return judge_cli(run_cli(["-m", "hardware.check", str(tmp / "nowhere.yaml")], timeout=60), "nowhere.yaml")


@probe("hardware.check", "--connect to an xArm that does not answer (loopback, nothing listening)")
def _(tmp):
    # The file is valid, the device does not answer: hardware.check exits 1 for that (2 is an invalid file: a
    # script can tell "fix the file" from "fix the cable / power, then retry"). Clear: one line on stderr
    # naming the address and the setup file, no traceback, within seconds.
    path = setup_yaml(tmp, lambda c: c.update(cameras={}, tactile={}))
    t0 = time.monotonic()
    res = run_cli(["-m", "hardware.check", str(path), "--connect", "--seconds", "0.1"], timeout=90)
    took, err = time.monotonic() - t0, res.stderr.strip()
    if (res.returncode == 1 and "Traceback" not in err and len(err.splitlines()) == 1 and "127.0.0.1" in err
            and str(path) in err and took < 15):
        return CLEAR, f"exit 1 after {took:.1f} s: {err[:200]}"
    return judge_cli(res, "127.0.0.1", str(path))
