"""Safety between the policy and the arm: workspace box, largest step, gripper limits, watchdog.

:class:`SafetyFilter` turns a policy action ``[x, y, z, yaw, gripper]`` into a target the arm may
take: clamped into the workspace box, moved at most ``max_step_m`` and ``max_rotation_rad`` from the
previous command, kept within ``max_tracking_m`` of the measured position, gripper clipped to its limits. A non-finite action or a measured pose outside the box
is a :class:`SafetyViolation` (the loop then stops the arm). :class:`Watchdog` stops the arm when no
fresh command or sensor frame arrived within its timeout (two control periods by default).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass

from controltac_il.config import STRICT, is_real, one_line_errors
from hardware.fields import Float, Problems, Vec3
from hardware.interfaces import ACTION_DIM, POSE_DIM, Clock, HardwareError


class SafetyViolation(HardwareError):
    """An action or a measured state broke a safety limit that cannot be clamped."""


class WatchdogTimeout(HardwareError):
    """No fresh command or sensor frame within the watchdog timeout."""


MAX_WORKSPACE_M = 2.0  # m from the base: beyond any tabletop arm's reach (a UR10e's is 1.3 m)
FULL_CIRCLE_SLACK = 1e-4  # rad: a yaw range this close to 2 pi (e.g. +-3.14159, 5e-6 short) is the full circle


def wrap_angle(a):
    """Angle(s) wrapped into [-pi, pi); angles already inside are returned exactly."""
    a = np.asarray(a, dtype=np.float64)
    r = (a + np.pi) % (2 * np.pi) - np.pi
    r = np.where(r >= np.pi, r - 2 * np.pi, r)  # just below -pi, the modulo rounds up to 2 pi: pi, not -pi
    return np.where((a >= -np.pi) & (a < np.pi), a, r)


@one_line_errors
@pydantic_dataclass(frozen=True, config=STRICT)
class SafetyLimits:
    """Limits enforced on every command; validated at construction (ValueError naming the field).

    workspace_min / workspace_max: corners (x, y, z) of the allowed end-effector box, metres, base frame, within
        ±MAX_WORKSPACE_M; required: the box is the set-up's to state.
    yaw_min / yaw_max: allowed yaw range, radians (within [-pi, pi]).
    max_step_m: largest translation between two consecutive commands, metres per control period
        (at most 0.1 m: 1 m/s at 10 Hz; a robot setup file further bounds it to 0.25 m/s at its rate).
    max_rotation_rad: largest yaw change between two consecutive commands, radians (at most 0.5; a robot
        setup file: 1 rad/s at its rate). Over the full circle (the default range) yaw turns the short way,
        through ±pi; a narrower range is an arc (yaw_min counter-clockwise to yaw_max) the wrist never leaves: a
        wanted yaw outside it goes to its nearer end, and yaw turns along the arc, never through the band it
        excludes.
    max_tracking_m: largest distance between a command and the last measured position, metres (at least
        max_step_m, at most 0.2; None: two steps, 2 x max_step_m): an arm blocked by contact is not pressed
        harder as the policy's targets walk on, since position control pushes in proportion to that gap;
        further commands are pulled toward the measured position. That pull may move a command by more than
        max_step_m, always back toward where the arm is, never away from it.
    gripper_min / gripper_max: allowed gripper command range within [0, 1] (0 open, 1 closed).
    state_tolerance_m: a measured pose further than this outside the box is a violation (arm stopped).
    state_tolerance_rad: a measured yaw further than this outside a narrower yaw range is a violation.
    """

    workspace_min: Vec3
    workspace_max: Vec3
    yaw_min: Float = Field(-np.pi, ge=-np.pi, le=np.pi)
    yaw_max: Float = Field(np.pi, ge=-np.pi, le=np.pi)
    max_step_m: Float = Field(0.02, gt=0, le=0.1)
    max_rotation_rad: Float = Field(0.1, gt=0, le=0.5)
    max_tracking_m: Float | None = Field(None, gt=0, le=0.2)
    gripper_min: Float = Field(0.0, ge=0, le=1)
    gripper_max: Float = Field(1.0, ge=0, le=1)
    state_tolerance_m: Float = Field(0.02, gt=0, le=0.2)
    state_tolerance_rad: Float = Field(0.05, gt=0, le=0.5)

    @model_validator(mode="after")
    def _ordered(self):
        problems = Problems("SafetyLimits")
        for name in ("workspace_min", "workspace_max"):  # millimetres would pass every other check
            if max(abs(v) for v in getattr(self, name)) > MAX_WORKSPACE_M:
                problems.add(name, f"must lie within ±{MAX_WORKSPACE_M:g} m of the base (metres, not mm)",
                             list(getattr(self, name)))
        if not all(lo < hi for lo, hi in zip(self.workspace_min, self.workspace_max)):
            problems.add("workspace_min", f"must be below workspace_max on every axis (workspace_max "
                         f"{list(self.workspace_max)})",
                         list(self.workspace_min))
        if not self.yaw_min < self.yaw_max:
            problems.add("yaw_min", f"must be below yaw_max ({self.yaw_max})", self.yaw_min)
        if self.max_tracking_m is not None and self.max_tracking_m < self.max_step_m:  # never one step ahead
            problems.add("max_tracking_m", f"must be at least max_step_m ({self.max_step_m})", self.max_tracking_m)
        if not self.gripper_min < self.gripper_max:
            problems.add("gripper_min", f"must be below gripper_max ({self.gripper_max})", self.gripper_min)
        problems.raise_any()
        return self

    @property
    def tracking_m(self) -> float:
        """The largest command-to-measured distance in force, metres (``max_tracking_m`` or two steps)."""
        return self.max_tracking_m if self.max_tracking_m is not None else 2 * self.max_step_m

    @property
    def full_circle(self) -> bool:
        """Whether every yaw is allowed (the range spans 2 pi, to within FULL_CIRCLE_SLACK): yaw wraps through ±pi."""
        return self.yaw_max - self.yaw_min >= 2 * np.pi - FULL_CIRCLE_SLACK

    def arc_position(self, yaw: float) -> float:
        """Where heading ``yaw`` (rad) lies along the yaw range, an arc from yaw_min counter-clockwise to yaw_max:
        in [0, yaw_max - yaw_min] inside it; outside, past the nearer end (below 0 nearer yaw_min)."""
        u = float((yaw - self.yaw_min) % (2 * np.pi))
        span = self.yaw_max - self.yaw_min
        return u - 2 * np.pi if u > span and 2 * np.pi - u < u - span else u


def checked_limits(limits) -> SafetyLimits:
    """``limits`` where it is :class:`SafetyLimits`; else ValueError (no workspace box is ever assumed)."""
    if not isinstance(limits, SafetyLimits):
        raise ValueError(f"limits: expected SafetyLimits (the workspace box is the caller's to state), got "
                         f"{type(limits).__name__}")
    return limits


@dataclass
class SafetyCounts:
    """How many commands each limit changed (clamps are counted, never silent)."""

    workspace: int = 0
    yaw_range: int = 0
    step: int = 0
    rotation: int = 0
    tracking: int = 0
    gripper: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class SafetyFilter:
    """Apply :class:`SafetyLimits` to a stream of actions ``[x, y, z, yaw, gripper]``."""

    def __init__(self, limits: SafetyLimits):
        self.limits = checked_limits(limits)
        self.counts = SafetyCounts()
        self._last: np.ndarray | None = None  # last commanded pose (4,)
        self._measured: np.ndarray | None = None  # last measured pose (4,)

    def reset(self, pose: np.ndarray) -> None:
        """Start from the measured pose (4,); the first command moves at most one step from it."""
        self.check_state(pose)
        self._last = np.asarray(pose, dtype=np.float64).copy()

    def check_state(self, pose: np.ndarray) -> None:
        """Raise :class:`SafetyViolation` when the measured pose is non-finite, outside the box by more than
        ``state_tolerance_m``, or (a range narrower than the full circle) its yaw outside the range by more than
        ``state_tolerance_rad``; else the next commands stay within ``max_tracking_m`` of it."""
        p = np.asarray(pose, dtype=np.float64)
        if p.shape != (POSE_DIM,) or not np.isfinite(p).all():
            raise SafetyViolation(f"measured pose must be 4 finite numbers [x, y, z, yaw], got {p!r}")
        tol = self.limits.state_tolerance_m
        lo, hi = np.asarray(self.limits.workspace_min), np.asarray(self.limits.workspace_max)
        if (p[:3] < lo - tol).any() or (p[:3] > hi + tol).any():
            raise SafetyViolation(
                f"measured position {np.round(p[:3], 4).tolist()} m is outside the workspace box "
                f"{list(lo)}..{list(hi)} by more than {tol} m"
            )
        self._measured = p.copy()
        lim = self.limits
        if lim.full_circle:
            return
        u, tol = lim.arc_position(p[3]), lim.state_tolerance_rad
        if not -tol <= u <= lim.yaw_max - lim.yaw_min + tol:
            raise SafetyViolation(f"measured yaw {float(wrap_angle(p[3])):.4f} rad is outside the yaw range "
                                  f"[{lim.yaw_min}, {lim.yaw_max}] by more than {tol} rad")

    def __call__(self, action: np.ndarray) -> np.ndarray:
        """Safe target (5,) float64 for ``action`` (5,); requires :meth:`reset` first."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (ACTION_DIM,):
            raise SafetyViolation(f"action must have shape ({ACTION_DIM},) [x, y, z, yaw, gripper], got {a.shape}")
        if not np.isfinite(a).all():
            raise SafetyViolation(f"action contains NaN or inf: {a.tolist()}")
        if self._last is None:
            raise RuntimeError("SafetyFilter.reset(measured_pose) must be called before the first action")
        lim, out = self.limits, a.copy()
        lo, hi = np.asarray(lim.workspace_min), np.asarray(lim.workspace_max)
        xyz = np.clip(a[:3], lo, hi)
        self.counts.workspace += int(not np.array_equal(xyz, a[:3]))
        delta = xyz - self._last[:3]
        dist = float(np.linalg.norm(delta))
        if dist > lim.max_step_m:
            xyz = self._last[:3] + delta * (lim.max_step_m / dist)
            self.counts.step += 1
        gap = xyz - self._measured[:3]
        ahead = float(np.linalg.norm(gap))
        if ahead > lim.tracking_m:
            xyz = np.clip(self._measured[:3] + gap * (lim.tracking_m / ahead), lo, hi)  # measured: maybe just outside
            self.counts.tracking += 1
        yaw = self._yaw(a[3])
        grip = float(np.clip(a[4], lim.gripper_min, lim.gripper_max))
        self.counts.gripper += int(grip != a[4])
        out[:3], out[3], out[4] = xyz, yaw, grip
        self._last = out[:POSE_DIM].copy()
        return out

    def _yaw(self, wanted: float) -> float:
        """The commanded yaw (rad) for a wanted one, at most ``max_rotation_rad`` from the last command: the short
        way over the full circle; on a narrower range clipped to its nearer end, then along the arc."""
        lim = self.limits
        step = lim.max_rotation_rad
        if lim.full_circle:
            last, yaw = float(wrap_angle(self._last[3])), float(wrap_angle(wanted))
            move = float(wrap_angle(yaw - last))
        else:
            last, target = lim.arc_position(self._last[3]), lim.arc_position(wanted)
            along = float(np.clip(target, 0.0, lim.yaw_max - lim.yaw_min))
            self.counts.yaw_range += int(along != target)
            last, move = last + lim.yaw_min, along - last
            yaw = float(wrap_angle(lim.yaw_min + along))
        if abs(move) > step:
            self.counts.rotation += 1
            return float(wrap_angle(last + np.sign(move) * step))
        return yaw


@dataclass
class Watchdog:
    """Trips when a feed (``"command"``, ``"frame:<name>"``) has not been fed within ``timeout_s``.

    timeout_s: seconds a feed may stay silent (two control periods in the loop).
    A feed is watched from its first :meth:`feed`. :meth:`check` raises :class:`WatchdogTimeout`;
    :meth:`start` runs the check in a thread that calls ``on_trip`` (e.g. ``arm.stop``) at once, so
    the arm stops even when the control thread hangs inside a device call.
    """

    timeout_s: float
    clock: Clock
    _fed: dict = field(default_factory=dict, repr=False)
    tripped: str | None = None

    def __post_init__(self):
        if not (is_real(self.timeout_s) and self.timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {self.timeout_s!r}")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def feed(self, name: str, t: float) -> None:
        """Record that ``name`` was fresh at clock time ``t`` (s). A ``t`` that is not a time already reached on
        ``clock`` (NaN, inf, or ahead of it: a source stamping frames with another clock) would keep the feed fresh
        for ever: :class:`SafetyViolation`."""
        now = self.clock.now()
        if not (is_real(t) and t <= now):
            raise SafetyViolation(f"watchdog: {name.replace(':', ' ')} stamped {t!r}, not a time on the loop's clock "
                                  f"(now {now:.3f} s): stamp frames with the loop's clock")
        with self._lock:
            self._fed[name] = max(t, self._fed.get(name, -np.inf))

    def check(self, now: float | None = None) -> None:
        """Raise :class:`WatchdogTimeout` (and remember it) when a feed is older than the timeout."""
        now = self.clock.now() if now is None else now
        if not is_real(now):  # NaN: every age would compare False, never a trip
            raise SafetyViolation(f"watchdog: checked at {now!r}, not a time")
        with self._lock:
            if self.tripped is None:
                for name, t in self._fed.items():
                    if now - t > self.timeout_s:
                        self.tripped = (
                            f"watchdog: no fresh {name.replace(':', ' ')} for {now - t:.3f} s "
                            f"(limit {self.timeout_s:.3f} s)"
                        )
                        break
            if self.tripped is not None:
                raise WatchdogTimeout(self.tripped)

    def start(self, on_trip: Callable[[], None], interval_s: float | None = None) -> None:
        """Check in a daemon thread every ``interval_s`` clock seconds (default timeout/4); call ``on_trip``
        once on a trip. The thread waits on ``clock``, so a virtual clock drives it deterministically."""
        interval = self.timeout_s / 4 if interval_s is None else interval_s

        def run():
            try:
                while not self.clock.wait(self._stop, interval):
                    try:
                        self.check()
                    except WatchdogTimeout:
                        on_trip()
                        return
            finally:
                self.clock.detach(self._thread)

        self._thread = threading.Thread(target=run, name="watchdog", daemon=True)
        self.clock.attach(self._thread, follows=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the checking thread (if started)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
