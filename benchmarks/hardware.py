"""Hardware benchmark without hardware: control-loop timing, GelSight frame latency, serial round trips.

    python -m benchmarks.hardware --out hardware.json            # about 45 s
    python -m benchmarks.hardware --quick --out hardware.json    # about 15 s

1. Control loop at 10 Hz on the wall clock with fake devices (arm, gripper, a 240x320 camera and two
   tactile sources) and an asynchronous policy that takes ``--policy-ms`` per chunk: |period error|
   p50 / p99 / max, time per cycle, inference time, missed deadlines.
2. GelSight reader on a video file (MJPEG like the sensor's UVC stream, written here from the tactile sensor model at the raw size
   ``--raw-hw``, played at 25 fps): per-frame crop + resize + convert time and the age of the newest
   frame when a 10 Hz consumer reads it.
3. Serial round trips through the real client stacks to emulated devices on a pseudo-terminal:
   Dynamixel Present Position read (dynamixel_sdk, Protocol 2.0) and Robotiq status read (pyserial,
   Modbus RTU). A pty has no wire: on a real bus add bytes x 10 / baud (e.g. 26 bytes at 57600 baud = 4.5 ms).
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import base_parser, print_table, write_results
from controltac_il.streams import LOOP_STATE
from controltac_il.tactile.spec import IMAGE_SIDE_PX

PROG = "python -m benchmarks.hardware"


def _stats_ms(values) -> dict:
    v = np.asarray(values, dtype=np.float64) * 1e3
    return {"p50_ms": float(np.percentile(v, 50)), "p99_ms": float(np.percentile(v, 99)), "max_ms": float(v.max()),
            "n": int(v.size)}


def control_loop(steps: int, policy_ms: float) -> dict:
    from hardware.control_loop import ControlLoop, ControlLoopConfig
    from hardware.fakes import FAKE_WORKSPACE, FakeArm, FakeGripper, SyntheticFrameSource
    from hardware.safety import SafetyLimits

    def slow_hold(obs):  # any callable is a policy; this one takes policy_ms of wall time, on purpose
        time.sleep(policy_ms / 1e3)
        return np.tile(np.r_[obs[LOOP_STATE][:4] + [0.0005, 0, 0, 0], 0.5], (20, 1))

    loop = ControlLoop(
        FakeArm(), slow_hold, gripper=FakeGripper(),
        cameras={"third_view": SyntheticFrameSource("third_view")},
        tactile={s: SyntheticFrameSource(s, background=True) for s in ("left", "right")},
        config=ControlLoopConfig(rate_hz=10.0, inference="async"), limits=SafetyLimits(**FAKE_WORKSPACE),
    )
    stats = loop.run(max_steps=steps)
    s = stats.summary()
    errors = np.abs(stats.period_errors_s())
    return {"steps": s["steps"], "rate_hz": 10.0, "policy_ms": policy_ms,
            "period_error": _stats_ms(errors), "cycle_work": _stats_ms(stats.work_s),
            "inference": _stats_ms(stats.inference_s), "deadline_misses": s["deadline_misses"]}


def gelsight_latency(seconds: float, raw_hw: tuple[int, int]) -> dict:
    from controltac_il.tactile import SensorSpec, TactileSensor
    from hardware.cameras import GelSightMini

    sensor = TactileSensor(SensorSpec.gelsight_mini(), optics="polynomial", seed=0)
    frames = [sensor.background] * 10 + [sensor.press("big_sphere", pose=(x, 0.0, 0.0), force=(0, 0, 5.0)).image
                                         for x in np.linspace(-3, 3, 15)]
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "gelsight.avi")
        h, w = raw_hw
        writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
        for f in frames:
            writer.write(cv2.resize(cv2.cvtColor(f, cv2.COLOR_RGB2BGR), (w, h), interpolation=cv2.INTER_LINEAR))
        writer.release()
        ages = []
        with GelSightMini("left", path, background_frames=10, loop_file=True) as gs:
            first = gs.latest()
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                time.sleep(0.1)
                ages.append(time.monotonic() - gs.latest().timestamp)
            last = gs.latest()
            fps = (last.index - first.index) / (last.timestamp - first.timestamp)
            process = list(gs.process_s)
    return {"raw_hw": list(raw_hw), "out_hw": [240, 320], "file_fps": 25.0, "delivered_fps": fps,
            "crop_resize": _stats_ms(process), "newest_frame_age": _stats_ms(ages)}


def serial_round_trips(n: int) -> dict:
    from hardware.dynamixel import DynamixelGripper
    from hardware.fake_serial import FakeDynamixelServo, FakeRobotiq2F85
    from hardware.robotiq import RobotiqGripper

    def read_times(gripper) -> dict:
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            gripper.state()
            times.append(time.perf_counter() - t0)
        return _stats_ms(times)

    out = {}
    with FakeDynamixelServo() as dev, DynamixelGripper(dev.port) as g:
        out["dynamixel_read_present_position"] = read_times(g)
    with FakeRobotiq2F85() as dev, RobotiqGripper(dev.port) as g:
        out["robotiq_read_status"] = read_times(g)
    return out


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=None, help="control-loop cycles (default 300, quick 100)")
    p.add_argument("--policy-ms", type=float, default=25.0, help="simulated policy inference time per chunk (ms)")
    p.add_argument("--raw-hw", type=int, nargs=2, default=(600, 800), metavar=("H", "W"),
                   help="raw GelSight frame size written to the video file (before the 15%% crop)")
    args = p.parse_args(argv)
    if args.steps is not None and args.steps < 1:
        p.error(f"--steps must be an int >= 1 (control-loop cycles), got {args.steps}")
    if not (math.isfinite(args.policy_ms) and args.policy_ms >= 0):
        p.error(f"--policy-ms must be a finite number >= 0 (ms per chunk), got {args.policy_ms}")
    lo, hi = IMAGE_SIDE_PX
    if not all(lo <= v <= hi for v in args.raw_hw):
        p.error(f"--raw-hw H W must be pixels, each in [{lo}, {hi}], got {args.raw_hw[0]} {args.raw_hw[1]}")
    steps = args.steps or (100 if args.quick else 300)
    loop = control_loop(steps, args.policy_ms)
    gel = gelsight_latency(3.0 if args.quick else 8.0, tuple(args.raw_hw))
    ser = serial_round_trips(100 if args.quick else 300)

    rows = [
        {"measure": "loop |period error|", **{k: v for k, v in loop["period_error"].items()}},
        {"measure": "loop cycle work", **loop["cycle_work"]},
        {"measure": f"policy call ({args.policy_ms:g} ms, async)", **loop["inference"]},
        {"measure": f"GelSight crop+resize {args.raw_hw[0]}x{args.raw_hw[1]}", **gel["crop_resize"]},
        {"measure": "GelSight newest-frame age at 10 Hz read", **gel["newest_frame_age"]},
        {"measure": "Dynamixel read (pty)", **ser["dynamixel_read_present_position"]},
        {"measure": "Robotiq status read (pty)", **ser["robotiq_read_status"]},
    ]
    print_table(rows, ["measure", "p50_ms", "p99_ms", "max_ms", "n"], title="hardware path timings (ms)")
    print(f"\ncontrol loop: {loop['steps']} cycles at 10 Hz, {loop['deadline_misses']} missed deadlines; "
          f"GelSight file source delivered {gel['delivered_fps']:.1f} fps (file at 25)")
    load = os.getloadavg()[0]
    print(f"machine load (1 min average) during the run: {load:.1f} on {os.cpu_count()} cores")
    return write_results(args.out, {"benchmark": "hardware", "quick": args.quick, "load_avg_1m": load, "control_loop": loop,
                                    "gelsight": gel, "serial": ser, "table": rows})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
