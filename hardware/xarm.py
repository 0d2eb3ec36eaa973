"""UFACTORY xArm (5/6/7) and its gripper through xarm-python-sdk.

The arm is driven in servo mode (mode 1, ``set_servo_cartesian``). In that mode the controller runs to
each point at full speed, so UFACTORY asks for small steps at a high rate; the adapter therefore
turns every 10 Hz target into a straight segment from the previous target and streams points along
it at ``stream_hz`` (100 Hz by default) from its own thread, arriving at the target after one control
period. Error and warning codes are read every cycle (``get_err_warn_code``); an error code, a
non-zero API return code (also from the streaming thread) or a lost connection raises
:class:`ArmFault` naming the code and its meaning (the SDK's code table). On connect, errors and
warnings are cleared and motion enabled; ``stop`` halts the stream and puts the arm in the stop state
(4); after a stop, ``servo`` refuses until ``connect`` is called again; ``close`` disconnects.

Interpolation and streaming run on the injected :class:`~hardware.interfaces.Clock` (the wall clock by
default): :meth:`XArm.stream_tick` sends one point for ``clock.now()``; the streaming thread calls it
every ``1 / stream_hz`` clock seconds, so on a :class:`~hardware.interfaces.VirtualClock` the stream
is exact and tests need no sleeps.

Tests replace ``XArmAPI`` at the SDK boundary (the ``api`` argument): its controller needs a real arm
or UFACTORY's simulator, which cannot run here.
"""

from __future__ import annotations

import threading

import numpy as np
from scipy.spatial.transform import Rotation

from controltac_il.config import one_line
from controltac_il.extras import require
from hardware.interfaces import (Arm, ArmFault, ArmState, Clock, ForceSample, ForceSensor, Gripper, GripperState, HardwareError,
                                 SensorError, WallClock)
from hardware.net import preflight, unreachable
from hardware.pose import tilt_problem, tool_rotation, yaw_of
from hardware.safety import wrap_angle

MODE_SERVO = 1
CONTROL_PORT = 502  # the controller's TCP command port (xarm-python-sdk: XCONF.SocketConf.TCP_CONTROL_PORT)
STATE_MOTION, STATE_STOP = 0, 4


def _describe(code: int, kind: str) -> str:
    try:
        from xarm.core.config.x_code import ControllerError, ControllerWarn

        title = (ControllerError if kind == "error" else ControllerWarn)(code, status=0).title
        return title.get("en", "") if isinstance(title, dict) else str(title)
    except Exception:  # noqa: BLE001 - the description is a courtesy; the code is what matters
        return ""


class XArm(Arm):
    """xArm arm in servo mode.

    ip: controller address. tool_rpy: (roll, pitch) of the tool at yaw 0, rad (default pointing down:
    (pi, 0)). period_s: control period; each target is reached this long after ``servo``.
    stream_hz: rate of the interpolated points (None: send each target as it comes, one point per
    ``servo``). api: an ``xarm.wrapper.XArmAPI`` (created from ``ip`` on connect when None).
    stop_on_warning: treat controller warnings as faults too (default: report them in ArmState only).
    clock: time of the state stamps, the segments and the stream (default: the wall clock).
    connect_timeout_s: when ``api`` is None, ``connect`` first checks that the controller accepts a TCP
    connection on ``port`` within this many seconds (None: no check); a controller that cannot be
    reached, or an SDK that fails to connect, is an :class:`ArmFault` naming the address.
    """

    def __init__(self, ip: str, tool_rpy: tuple[float, float] = (np.pi, 0.0), period_s: float = 0.1,
                 stream_hz: float | None = 100.0, api=None, stop_on_warning: bool = False,
                 clock: Clock | None = None, connect_timeout_s: float | None = 3.0, port: int = CONTROL_PORT):
        if not period_s > 0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        if stream_hz is not None and not stream_hz * period_s >= 1:
            raise ValueError(f"stream_hz must be at least the control rate 1/period_s, got {stream_hz}")
        self.ip, self.api, self.stop_on_warning = ip, api, stop_on_warning
        self.connect_timeout_s, self.port = connect_timeout_s, port
        self.period_s, self.stream_hz = period_s, stream_hz
        self.r0 = Rotation.from_euler("xyz", [tool_rpy[0], tool_rpy[1], 0.0])
        self.clock = clock or WallClock()
        self._lock = threading.Lock()
        self._segment: tuple[np.ndarray, np.ndarray, float] | None = None  # start, end [x,y,z,yaw], t0
        self._stream_error: str | None = None
        self._stopped = False
        self._stream_stop = threading.Event()
        self._streamer: threading.Thread | None = None

    def _fault(self, msg: str) -> ArmFault:
        return ArmFault(f"xArm {self.ip}: {msg}")

    def _ok(self, code: int, what: str) -> None:
        if code != 0:
            raise self._fault(f"{what} returned API code {code}")

    def connect(self) -> None:
        if self.api is None:
            wrapper = require("xarm.wrapper", "xarm", "the xArm")  # before the network: a missing extra says so
            preflight("xArm", self.ip, self.port, self.connect_timeout_s)
            try:
                self.api = wrapper.XArmAPI(self.ip, is_radian=True)
            except Exception as exc:  # noqa: BLE001 - the SDK raises a bare Exception("connect socket failed")
                raise unreachable("xArm", self.ip, one_line(exc)) from None
        if not self.api.connected:
            raise unreachable("xArm", self.ip, "the SDK reports no connection")
        self.api.clean_error()
        self.api.clean_warn()
        self._ok(self.api.motion_enable(enable=True), "motion_enable")
        self._ok(self.api.set_mode(MODE_SERVO), "set_mode(1)")
        self._ok(self.api.set_state(STATE_MOTION), "set_state(0)")
        with self._lock:
            self._segment, self._stream_error, self._stopped = None, None, False
        self.check()
        if self.stream_hz is not None and self._streamer is None:
            self._stream_stop.clear()
            self._streamer = threading.Thread(target=self._stream, name=f"xarm-stream-{self.ip}", daemon=True)
            self.clock.attach(self._streamer, follows=True)
            self._streamer.start()

    def check(self) -> tuple[int, int]:
        """Read (error, warning) codes; raise ArmFault on an error (or a warning with stop_on_warning),
        on a failed streamed point, or when the connection is gone."""
        if self.api is None or not self.api.connected:
            raise self._fault("connection lost")
        if self._stream_error is not None:
            raise self._fault(self._stream_error)
        code, (err, warn) = self.api.get_err_warn_code()
        self._ok(code, "get_err_warn_code")
        if err:
            raise self._fault(f"controller error code {err} ({_describe(err, 'error')}); clear it on the controller")
        if warn and self.stop_on_warning:
            raise self._fault(f"controller warning code {warn} ({_describe(warn, 'warn')})")
        return err, warn

    def state(self) -> ArmState:
        err, warn = self.check()
        code, pose = self.api.get_position(is_radian=True)
        self._ok(code, "get_position")
        x, y, z, roll, pitch, yaw = pose
        r = Rotation.from_euler("xyz", [roll, pitch, yaw])
        problem = tilt_problem(r, self.r0, "tool_rpy")
        if problem:
            raise self._fault(problem)
        return ArmState(np.array([x / 1000, y / 1000, z / 1000, yaw_of(r, self.r0)]), self.clock.now(), err, warn)

    def _send(self, pose4: np.ndarray) -> int:
        x, y, z, yaw = (float(v) for v in pose4)
        roll, pitch, yaw_x = tool_rotation(yaw, self.r0).as_euler("xyz")
        return self.api.set_servo_cartesian([x * 1000, y * 1000, z * 1000, roll, pitch, yaw_x], is_radian=True)

    def servo(self, target) -> None:
        if self._stopped:
            raise self._fault("stopped; call connect() to enable motion again")
        self.check()
        target = np.asarray(target, dtype=np.float64)
        if self.stream_hz is None:
            self._ok(self._send(target), "set_servo_cartesian")
            return
        with self._lock:
            if self._segment is None:  # first target: start from where the arm is
                start = self.state().pose
            else:  # from wherever the current segment has got to
                s, e, t0 = self._segment
                start = s + min(1.0, (self.clock.now() - t0) / self.period_s) * self._delta(s, e)
            self._segment = (start, target, self.clock.now())

    @staticmethod
    def _delta(s: np.ndarray, e: np.ndarray) -> np.ndarray:
        d = e - s
        d[3] = float(wrap_angle(d[3]))  # yaw the short way round
        return d

    def stream_tick(self) -> None:
        """Send the point of the current segment for ``clock.now()`` (nothing before the first target or
        after a stop); a non-zero API code is kept and raised by the next :meth:`check`."""
        with self._lock:
            seg = None if self._stopped else self._segment
            if seg is None:
                return
            s, e, t0 = seg
            alpha = min(1.0, (self.clock.now() - t0) / self.period_s)
            code = self._send(s + alpha * self._delta(s, e))
            if code != 0 and self._stream_error is None:
                self._stream_error = f"set_servo_cartesian returned API code {code} while streaming"

    def _stream(self) -> None:
        """Streaming thread: one :meth:`stream_tick` every 1 / stream_hz clock seconds."""
        dt = 1.0 / self.stream_hz
        next_t = self.clock.now()
        try:
            while True:
                next_t = max(next_t + dt, self.clock.now())
                if self.clock.wait(self._stream_stop, max(0.0, next_t - self.clock.now())):
                    return
                self.stream_tick()
        finally:
            self.clock.detach()

    def stop(self) -> None:
        """Halt the point stream, then the stop state (4): the controller drops the servo target and halts."""
        self._stopped = True  # no lock: the stream may be blocked inside a send; it checks this before each point
        if self.api is not None:
            self.api.set_state(STATE_STOP)

    def close(self) -> None:
        self._stream_stop.set()
        if self._streamer is not None and self._streamer is not threading.current_thread():
            self._streamer.join(timeout=1.0)
            self._streamer = None
        if self.api is not None:
            self.api.disconnect()


class XArmGripper(Gripper):
    """The xArm gripper, on the same SDK connection as the arm (pass ``arm``; connect the arm first).

    open_position / closed_position: SDK gripper units (850 open, 0 closed by default). speed: pulse/s.
    """

    def __init__(self, arm: XArm, open_position: float = 850.0, closed_position: float = 0.0,
                 speed: float = 5000.0, clock: Clock | None = None):
        if open_position == closed_position:
            raise ValueError("open_position and closed_position must differ (gripper units)")
        self.arm, self.open_position, self.closed_position, self.speed = arm, open_position, closed_position, speed
        self.clock = clock or WallClock()

    def _api(self):
        if self.arm.api is None:
            raise HardwareError(f"xArm gripper {self.arm.ip}: connect the arm first")
        return self.arm.api

    def _check(self, code: int, what: str) -> None:
        if code != 0:
            _, err = self._api().get_gripper_err_code()
            raise HardwareError(f"xArm gripper {self.arm.ip}: {what} returned API code {code} (gripper error {err})")

    def connect(self) -> None:
        api = self._api()
        api.clean_gripper_error()
        self._check(api.set_gripper_mode(0), "set_gripper_mode(0)")
        self._check(api.set_gripper_enable(True), "set_gripper_enable")
        self._check(api.set_gripper_speed(self.speed), "set_gripper_speed")

    def command(self, closing: float) -> None:
        if not 0.0 <= closing <= 1.0:
            raise ValueError(f"gripper command must be in [0, 1] (0 open, 1 closed), got {closing}")
        pos = self.open_position + closing * (self.closed_position - self.open_position)
        self._check(self._api().set_gripper_position(pos, wait=False), "set_gripper_position")

    def state(self) -> GripperState:
        code, pos = self._api().get_gripper_position()
        self._check(code, "get_gripper_position")
        frac = (pos - self.open_position) / (self.closed_position - self.open_position)
        return GripperState(float(np.clip(frac, 0.0, 1.0)), self.clock.now())

    def stop(self) -> None:
        """Nothing to send: the gripper holds its last target (a gripped object stays)."""


class XArmForce(ForceSensor):
    """The xArm's six-axis F/T sensor through the SDK: enabled and zeroed on ``start`` (out of contact; the
    controller then leaves the motion state, which is restored), then ``normal_n`` = |(Fx, Fy, Fz)| of
    ``get_ft_sensor_data`` (N): the press's reaction, whose shear is small while the finger presses straight.
    SDK names before and after 1.17 (``ft_sensor_enable`` / ``set_ft_sensor_enable``, ``..._set_zero`` /
    ``set_..._zero``) are both accepted. The arm must be connected first."""

    name = "xarm_ft"

    def __init__(self, arm: XArm):
        self.arm = arm

    def _sdk(self, names: tuple[str, ...]):
        """The SDK method of the first of ``names`` (its name in 1.17+, then before), or None."""
        return next((getattr(self.arm.api, n) for n in names if hasattr(self.arm.api, n)), None)

    def _call(self, names: tuple[str, ...], *args) -> None:
        fn = self._sdk(names)
        if fn is None:
            raise SensorError(f"xArm {self.arm.ip}: the SDK has no {names[0]} (an F/T sensor is needed)")
        code = fn(*args)
        if code != 0:
            raise SensorError(f"xArm {self.arm.ip}: {names[0]} returned API code {code}")

    def start(self) -> None:
        if self.arm.api is None:
            raise SensorError(f"xArm {self.arm.ip}: connect the arm before its F/T sensor")
        self._call(("set_ft_sensor_enable", "ft_sensor_enable"), 1)
        self._call(("set_ft_sensor_zero", "ft_sensor_set_zero"))
        self._call(("set_state",), STATE_MOTION)

    def read(self) -> ForceSample:
        code, data = self.arm.api.get_ft_sensor_data()
        force = np.asarray(data, dtype=np.float64).ravel()[:3] if code == 0 else np.full(3, np.nan)
        if force.shape != (3,) or not np.isfinite(force).all():
            raise SensorError(f"xArm {self.arm.ip}: get_ft_sensor_data returned code {code}, {data!r}")
        return ForceSample(float(np.linalg.norm(force)), self.arm.clock.now())

    def close(self) -> None:
        disable = self._sdk(("set_ft_sensor_enable", "ft_sensor_enable")) if self.arm.api is not None else None
        if disable is not None and self.arm.api.connected:
            disable(0)
