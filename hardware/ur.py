"""Universal Robots arm through ur-rtde.

Targets are streamed with ``servoL`` (lookahead time and gain from the config; each command is active
for one control period); the TCP pose comes from ``RTDEReceiveInterface.getActualTCPPose`` (m, rotation
vector). Every cycle checks the connection, the control script, protective and emergency stops and the
safety mode, and raises :class:`ArmFault` naming what it found. ``stop`` calls ``servoStop``; ``close``
calls ``stopScript`` and disconnects (so on exit: servoStop, then stopScript).

Tests replace the two RTDE interfaces at the SDK boundary (``control`` / ``receive`` arguments): they
need a robot or URSim, which cannot run here.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from controltac_il.config import one_line
from controltac_il.extras import require
from hardware.interfaces import (Arm, ArmFault, ArmState, Clock, ForceSample, ForceSensor, HardwareError, SensorError,
                                 WallClock)
from hardware.net import preflight, unreachable
from hardware.pose import tilt_problem, tool_rotation, yaw_of

SAFETY_MODES = {1: "normal", 2: "reduced", 3: "protective stop", 4: "recovery", 5: "safeguard stop",
                6: "system emergency stop", 7: "robot emergency stop", 8: "violation", 9: "fault",
                10: "validate joint id", 11: "undefined safety mode", 12: "automatic mode safeguard stop",
                13: "system three-position enabling stop"}
MOVING_SAFETY_MODES = (1, 2)
RTDE_PORT = 30004  # the controller's RTDE port


class URArm(Arm):
    """UR arm streamed with servoL.

    ip: controller address. tool_rotvec: tool orientation at yaw 0 as a rotation vector (default
    pointing down: (pi, 0, 0)). period_s: how long each servoL target is active (the control period).
    lookahead_time: servoL smoothing, 0.03-0.2 s. gain: servoL proportional gain, 100-2000.
    speed / acceleration: passed to servoL (unused by the controller in servo mode) and servoStop.
    control / receive: RTDEControlInterface / RTDEReceiveInterface (created from ``ip`` when None).
    connect_timeout_s: before creating them, ``connect`` checks that the controller accepts a TCP connection
    on ``port`` (RTDE, 30004) within this many seconds (None: no check); a controller that cannot be
    reached, or an RTDE interface that fails to connect, is an :class:`ArmFault` naming the address.
    """

    def __init__(self, ip: str, tool_rotvec=(np.pi, 0.0, 0.0), period_s: float = 0.1, lookahead_time: float = 0.1,
                 gain: float = 300.0, speed: float = 0.25, acceleration: float = 1.2, control=None, receive=None,
                 clock: Clock | None = None, connect_timeout_s: float | None = 3.0, port: int = RTDE_PORT):
        if not 0.03 <= lookahead_time <= 0.2:
            raise ValueError(f"lookahead_time must be in [0.03, 0.2] s, got {lookahead_time}")
        if not 100 <= gain <= 2000:
            raise ValueError(f"gain must be in [100, 2000], got {gain}")
        if not period_s > 0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        self.ip, self.period_s, self.lookahead_time, self.gain = ip, period_s, lookahead_time, gain
        self.speed, self.acceleration = speed, acceleration
        self.r0 = Rotation.from_rotvec(np.asarray(tool_rotvec, dtype=float))
        self.control, self.receive = control, receive
        self.connect_timeout_s, self.port = connect_timeout_s, port
        self.clock = clock or WallClock()

    def _fault(self, msg: str) -> ArmFault:
        return ArmFault(f"UR {self.ip}: {msg}")

    @contextlib.contextmanager
    def _sdk(self, what: str) -> Iterator[None]:
        """ur-rtde's RuntimeError (its C++ exceptions, e.g. a connection dropped mid-call) as an ArmFault naming
        ``what``: a device fault of the run, never a traceback. The adapter's own faults pass through."""
        try:
            yield
        except HardwareError:
            raise
        except RuntimeError as exc:
            raise self._fault(f"{what}: {one_line(exc)}") from None

    def connect(self) -> None:
        if self.receive is None or self.control is None:  # the SDK first: a missing extra needs no network to say so
            rtde_receive, rtde_control = (require(m, "ur", "the UR arm") for m in ("rtde_receive", "rtde_control"))
            preflight("UR", self.ip, self.port, self.connect_timeout_s)
        try:
            if self.receive is None:
                self.receive = rtde_receive.RTDEReceiveInterface(self.ip)
            if self.control is None:
                self.control = rtde_control.RTDEControlInterface(self.ip)
        except (RuntimeError, OSError) as exc:  # ur-rtde raises RuntimeError when it cannot connect
            raise unreachable("UR", self.ip, one_line(exc)) from None
        self.check()

    def check(self) -> None:
        """Raise ArmFault on a lost connection, a stopped script, a protective / emergency stop or a safety mode that cannot move."""
        if self.receive is None or self.control is None:
            raise self._fault("not connected (call connect())")
        if not self.receive.isConnected() or not self.control.isConnected():
            raise self._fault("RTDE connection lost")
        if self.receive.isEmergencyStopped():
            raise self._fault("emergency stop is active")
        if self.receive.isProtectiveStopped():
            raise self._fault("protective stop (collision or limit); unlock it on the teach pendant")
        mode = self.receive.getSafetyMode()
        if mode not in MOVING_SAFETY_MODES:
            raise self._fault(f"safety mode {mode} ({SAFETY_MODES.get(mode, 'unknown')})")
        if not self.control.isProgramRunning():
            raise self._fault("the RTDE control script is not running (stopped from the pendant?)")

    def state(self) -> ArmState:
        with self._sdk("reading the pose"):
            self.check()
            x, y, z, rx, ry, rz = self.receive.getActualTCPPose()
        r = Rotation.from_rotvec([rx, ry, rz])
        problem = tilt_problem(r, self.r0, "tool_rotvec")
        if problem:
            raise self._fault(problem)
        yaw = yaw_of(r, self.r0)
        return ArmState(np.array([x, y, z, yaw]), self.clock.now())

    def servo(self, target) -> None:
        x, y, z, yaw = (float(v) for v in target)
        pose = [x, y, z, *tool_rotation(yaw, self.r0).as_rotvec().tolist()]
        with self._sdk("servoL"):
            self.check()
            ok = self.control.servoL(pose, self.speed, self.acceleration, self.period_s, self.lookahead_time, self.gain)
        if ok is False:
            raise self._fault(f"servoL rejected the target {np.round(pose, 4).tolist()}")

    def stop(self) -> None:
        """servoStop: decelerate and leave servo mode."""
        if self.control is not None:
            with self._sdk("servoStop"):
                self.control.servoStop(self.acceleration * 4)

    def close(self) -> None:
        """stopScript and disconnect both interfaces."""
        with self._sdk("closing the RTDE interfaces"):
            if self.control is not None:
                self.control.stopScript()
                self.control.disconnect()
            if self.receive is not None:
                self.receive.disconnect()


class URForce(ForceSensor):
    """The e-series wrist F/T through the arm's RTDE interfaces: ``zeroFtSensor`` on ``start`` (out of contact),
    then ``normal_n`` = |(Fx, Fy, Fz)| of ``getActualTCPForce`` (N, base frame): the press's reaction, whose
    shear is small while the finger presses straight. The arm must be connected first."""

    name = "ur_wrist"

    def __init__(self, arm: URArm):
        self.arm = arm

    def start(self) -> None:
        if self.arm.control is None:
            raise SensorError(f"UR {self.arm.ip}: connect the arm before its wrist force sensor")
        self.arm.control.zeroFtSensor()

    def read(self) -> ForceSample:
        wrench = self.arm.receive.getActualTCPForce()
        force = np.asarray(wrench, dtype=np.float64)[:3]
        if force.shape != (3,) or not np.isfinite(force).all():
            raise SensorError(f"UR {self.arm.ip}: getActualTCPForce returned {wrench!r}, not 6 finite numbers")
        return ForceSample(float(np.linalg.norm(force)), self.arm.clock.now())
