"""In-memory devices for dry runs, tests and the benchmark (no hardware, no vendor SDK).

``FakeArm`` moves instantly to each target; faults can be injected (controller error code, a hang in
``servo``). ``FakeGripper`` follows its command. ``SyntheticFrameSource`` produces frames stamped with
the loop's clock and can be made to freeze (a sensor that stops delivering). Every device appends
``(event, value)`` to a shared ``log`` list, so tests can check the order of commands and stops.
"""

from __future__ import annotations

import threading

import numpy as np

from hardware.interfaces import (
    POSE_DIM,
    Arm,
    ArmFault,
    ArmState,
    Clock,
    Frame,
    FrameSource,
    Gripper,
    GripperState,
    SensorError,
    WallClock,
)


# the workspace box a dry run with FakeArm states (its start pose (0.4, 0, 0.2) m inside), as SafetyLimits' kwargs
FAKE_WORKSPACE = {"workspace_min": (0.2, -0.3, 0.0), "workspace_max": (0.7, 0.3, 0.5)}


class FakeArm(Arm):
    """Arm whose pose jumps to every target. ``error_code`` != 0 makes ``state``/``servo`` raise ArmFault;
    ``servo_delay_s`` makes each ``servo`` block that long (clock seconds: a VirtualClock lets the loop's
    watchdog thread run meanwhile), like a hung controller. Like the xArm, a stopped arm refuses ``servo`` until
    ``connect`` enables motion again."""

    def __init__(self, pose=(0.4, 0.0, 0.2, 0.0), clock: Clock | None = None, log: list | None = None):
        self.pose = np.asarray(pose, dtype=np.float64).copy()
        if self.pose.shape != (POSE_DIM,):
            raise ValueError(f"pose must be [x, y, z, yaw], got {pose!r}")
        self.clock = clock or WallClock()
        self.log = [] if log is None else log
        self.error_code = 0
        self.servo_delay_s = 0.0
        self.stopped = False

    def _check(self):
        if self.error_code:
            raise ArmFault(f"fake arm: controller error code {self.error_code}")

    def state(self) -> ArmState:
        self._check()
        return ArmState(self.pose.copy(), self.clock.now())

    def connect(self) -> None:
        self.log.append(("arm-connect", None))
        self.stopped = False

    def servo(self, target) -> None:
        self._check()
        if self.stopped:
            raise ArmFault("fake arm: stopped; call connect() to enable motion again")
        self.log.append(("servo", np.asarray(target, dtype=np.float64).copy()))
        if self.servo_delay_s:
            self.clock.sleep_until(self.clock.now() + self.servo_delay_s)
            self.log.append(("servo-returned", None))
        self.pose = np.asarray(target, dtype=np.float64).copy()

    def stop(self) -> None:
        self.log.append(("arm-stop", None))
        self.stopped = True


class FakeGripper(Gripper):
    """Gripper whose position equals its last command."""

    def __init__(self, clock: Clock | None = None, log: list | None = None):
        self.clock = clock or WallClock()
        self.log = [] if log is None else log
        self.position = 0.0

    def command(self, closing: float) -> None:
        self.log.append(("gripper", float(closing)))
        self.position = float(closing)

    def state(self) -> GripperState:
        return GripperState(self.position, self.clock.now())

    def stop(self) -> None:
        self.log.append(("gripper-stop", None))


class SyntheticFrameSource(FrameSource):
    """Frames (H, W, 3) of a coloured blob circling the image (16 pre-rendered positions), stamped
    with ``clock.now()`` at each ``latest``.

    ``freeze()`` keeps returning the last frame with its old timestamp (a stalled sensor);
    ``unplug()`` makes ``latest`` raise SensorError.
    """

    def __init__(self, name: str, shape=(240, 320), clock: Clock | None = None, background: bool = False):
        self.name, self.shape = name, tuple(shape)
        self.clock = clock or WallClock()
        self._index = 0
        self._frozen: Frame | None = None
        self._unplugged = False
        self._lock = threading.Lock()
        h, w = self.shape
        yy, xx = np.mgrid[0:h, 0:w]
        self._frames = []
        for k in range(16):
            cx, cy = w / 2 + 0.3 * w * np.cos(2 * np.pi * k / 16), h / 2 + 0.3 * h * np.sin(2 * np.pi * k / 16)
            img = np.full((h, w, 3), 100, np.uint8)
            img[..., 0] += (80 * ((xx - cx) ** 2 + (yy - cy) ** 2 < (min(h, w) / 6) ** 2)).astype(np.uint8)
            self._frames.append(img)
        self.background = np.full((h, w, 3), 100, np.uint8) if background else None

    def latest(self) -> Frame:
        with self._lock:
            if self._unplugged:
                raise SensorError(f"{self.name}: device unplugged")
            if self._frozen is not None:
                return self._frozen
            self._index += 1
            return Frame(self._frames[self._index % 16], self.clock.now(), self._index)

    def freeze(self) -> None:
        with self._lock:
            self._frozen = Frame(self._frames[self._index % 16], self.clock.now(), self._index)

    def unplug(self) -> None:
        with self._lock:
            self._unplugged = True
