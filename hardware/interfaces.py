"""Device interfaces shared by the control loop, the robot adapters and the MuJoCo robot.

Units everywhere: metres, radians, seconds. An end-effector pose or target is
``[x, y, z, yaw]`` in the robot base frame (tool pointing down; yaw about base z).
A gripper command or position is a float in ``[0, 1]``: 0 = fully open, 1 = fully closed.
Timestamps come from one :class:`Clock` (``time.monotonic()`` for real hardware; a simulated
robot supplies its own clock and stamps its frames with it).
"""

from __future__ import annotations

import abc
import threading
import time
from dataclasses import dataclass

import numpy as np

POSE_DIM = 4  # x, y, z (m), yaw (rad)
ACTION_DIM = 5  # pose + gripper command


class HardwareError(RuntimeError):
    """A device reported a fault or stopped answering; the message says which and why."""


class ArmFault(HardwareError):
    """The arm controller reported an error code, a protective stop or lost connection."""


class SensorError(HardwareError):
    """A camera or tactile sensor stopped delivering frames (e.g. unplugged)."""


@dataclass(frozen=True)
class ArmState:
    """Measured end-effector state.

    pose: float64 (4,) ``[x, y, z, yaw]`` in m and rad, robot base frame.
    timestamp: clock seconds when the state was read.
    error_code / warning_code: controller codes (0 = none), as the vendor reports them.
    """

    pose: np.ndarray
    timestamp: float
    error_code: int = 0
    warning_code: int = 0


@dataclass(frozen=True)
class GripperState:
    """Measured gripper opening: position in [0, 1] (0 open, 1 closed) and clock seconds."""

    position: float
    timestamp: float


@dataclass(frozen=True)
class Frame:
    """One image from a camera or tactile sensor.

    image: uint8 (H, W, 3) RGB. timestamp: clock seconds when it was captured.
    index: sequence number of the frame since the source started (increments by one per new frame).
    """

    image: np.ndarray
    timestamp: float
    index: int


class Clock(abc.ABC):
    """Time source of the control loop. ``realtime`` is True when ``now`` follows the wall clock."""

    realtime: bool = True

    @abc.abstractmethod
    def now(self) -> float:
        """Current time in seconds (monotonic)."""

    @abc.abstractmethod
    def sleep_until(self, t: float) -> None:
        """Return once ``now() >= t`` (immediately if already past)."""


class WallClock(Clock):
    """``time.monotonic`` with a sleep that wakes close to the deadline (coarse sleep, then spin)."""

    realtime = True

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        while True:
            left = t - time.monotonic()
            if left <= 0:
                return
            time.sleep(left - 0.001 if left > 0.002 else 0)


class VirtualClock(Clock):
    """Simulated time: ``sleep_until`` jumps forward at once, so a simulation runs faster than real time.

    Thread-safe; share one instance between a simulated robot (to stamp its frames) and the loop.
    """

    realtime = False

    def __init__(self, start: float = 0.0):
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def sleep_until(self, t: float) -> None:
        with self._lock:
            self._t = max(self._t, float(t))

    def advance(self, dt: float) -> None:
        """Move time forward by ``dt`` seconds (>= 0)."""
        if dt < 0:
            raise ValueError(f"dt must be >= 0 seconds, got {dt}")
        with self._lock:
            self._t += float(dt)


class _Device(abc.ABC):
    """Connect on ``__enter__``; on ``__exit__`` stop (whatever happened) and then close."""

    def connect(self) -> None:
        """Open the connection and make the device ready to move."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop motion now. Safe to call repeatedly, from any thread, and before ``connect``."""

    def close(self) -> None:
        """Release the connection (after ``stop``)."""

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.stop()
        finally:
            self.close()


class Arm(_Device):
    """An arm driven by end-effector targets streamed at the control rate."""

    @abc.abstractmethod
    def state(self) -> ArmState:
        """Measured pose; raises :class:`ArmFault` when the controller reports an error."""

    @abc.abstractmethod
    def servo(self, target: np.ndarray) -> None:
        """Stream one target ``[x, y, z, yaw]`` (m, rad), reached by the next control period.

        Raises :class:`ArmFault` when the controller rejects it or reports an error.
        """


class Gripper(_Device):
    """A parallel gripper commanded by a closing fraction."""

    @abc.abstractmethod
    def command(self, closing: float) -> None:
        """Move to ``closing`` in [0, 1] (0 open, 1 closed); returns without waiting."""

    @abc.abstractmethod
    def state(self) -> GripperState:
        """Measured opening in [0, 1] (0 open, 1 closed)."""


class FrameSource(abc.ABC):
    """A camera or tactile sensor that keeps its newest frame.

    ``name`` identifies it in observations (``images/<name>`` or ``tactile/<name>``);
    ``background`` is the no-contact image (uint8 (H, W, 3)) for tactile sensors, else None.
    """

    name: str = "camera"
    background: np.ndarray | None = None

    def start(self) -> None:
        """Open the device and begin capturing."""

    @abc.abstractmethod
    def latest(self) -> Frame:
        """Newest frame; raises :class:`SensorError` when the source has failed or has none yet."""

    def close(self) -> None:
        """Stop capturing and release the device."""

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
