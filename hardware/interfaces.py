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

from controltac_il.config import add_note

ACTION_NAMES = ("x", "y", "z", "yaw", "gripper")  # the action and qpos layout everywhere: m, m, m, rad, [0, 1]
POSE_DIM = ACTION_NAMES.index("gripper")  # the pose part, x, y, z (m), yaw (rad), comes first
GRIPPER = POSE_DIM  # index of the gripper command in an action
YAW = ACTION_NAMES.index("yaw")  # index of the yaw (rad), an angle
ACTION_DIM = len(ACTION_NAMES)  # pose + gripper command


class HardwareError(RuntimeError):
    """A device reported a fault or stopped answering; the message says which and why."""


try:  # what a serial line raises when its adapter is unplugged: pyserial's SerialException (an OSError), termios'
    from termios import error as _TermiosError

    SERIAL_ERRORS: tuple[type[BaseException], ...] = (OSError, _TermiosError)
except ImportError:  # not POSIX
    SERIAL_ERRORS = (OSError,)


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

    image: uint8 (H, W, 3) RGB. timestamp: seconds on the control loop's clock when it was captured (a stamp the loop's
    clock has not reached is refused by its watchdog).
    index: sequence number of the frame since the source started (increments by one per new frame).
    """

    image: np.ndarray
    timestamp: float
    index: int


@dataclass(frozen=True)
class ForceSample:
    """One contact-force reading: ``normal_n`` the force pressing on the tactile sensor (N, >= 0 while pressing),
    ``timestamp`` clock seconds when it was read."""

    normal_n: float
    timestamp: float


class Clock(abc.ABC):
    """Time source of the control loop and the adapters. ``realtime`` is True when ``now`` follows the wall clock.

    Threads that must finish their work before time moves on (the loop, the policy worker; watchdog,
    streaming and reader threads as followers) are registered with :meth:`attach` / :meth:`detach`, and
    wait with :meth:`wait` or :meth:`sleep_until`; on the wall clock these are plain waits, on a
    :class:`VirtualClock` they make multi-threaded runs deterministic.
    """

    realtime: bool = True

    @abc.abstractmethod
    def now(self) -> float:
        """Current time in seconds (monotonic)."""

    @abc.abstractmethod
    def sleep_until(self, t: float) -> None:
        """Return once ``now() >= t`` (immediately if already past)."""

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Wait until ``event`` is set or ``timeout_s`` clock seconds passed; True when it is set."""
        return event.wait(timeout_s)

    def attach(self, thread: threading.Thread | None = None, follows: bool = False) -> None:
        """Register ``thread`` (default: the caller) as one whose work time waits for (no-op on the wall clock).

        follows: the thread only follows time (a periodic check, a stream, a frame reader): time waits
        while it runs but never moves on for its sleeps alone.
        """

    def detach(self, thread: threading.Thread | None = None) -> None:
        """Undo one :meth:`attach` of ``thread`` (default: the caller)."""


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
    """Simulated time, deterministic with several threads.

    ``sleep_until`` / ``wait`` never wait on the wall clock for time to pass: time jumps to the earliest
    wake-up asked for as soon as no *attached* thread is running (every attached thread is sleeping
    in this clock or waiting on an event that is not set) and some thread that does not merely follow
    time is sleeping. With no attached thread, ``sleep_until`` jumps at once, as a single-threaded
    simulation expects. A test that checks state between steps attaches its own thread too, so time
    moves only when it sleeps; a follower (watchdog, stream, reader) left alone never runs time on.
    Thread-safe; share one instance between a simulated robot (to stamp its frames) and the loop.
    :meth:`advance` moves time by hand. Threads woken at the same instant run in no fixed order:
    tests pick times that do not tie.
    """

    realtime = False
    _POLL_S = 0.01  # events set by other threads are noticed within this many wall seconds

    def __init__(self, start: float = 0.0):
        self._t = float(start)
        self._cv = threading.Condition()
        self._attached: dict[threading.Thread, int] = {}
        self._followers: set[threading.Thread] = set()
        self._sleepers: list[tuple[threading.Thread, float, threading.Event | None]] = []

    def now(self) -> float:
        return self._t

    def attach(self, thread: threading.Thread | None = None, follows: bool = False) -> None:
        thread = thread or threading.current_thread()
        with self._cv:
            self._attached[thread] = self._attached.get(thread, 0) + 1
            if follows:
                self._followers.add(thread)
            self._cv.notify_all()

    def detach(self, thread: threading.Thread | None = None) -> None:
        thread = thread or threading.current_thread()
        with self._cv:
            n = self._attached.get(thread, 0) - 1
            if n > 0:
                self._attached[thread] = n
            else:
                self._attached.pop(thread, None)
                self._followers.discard(thread)
            self._cv.notify_all()

    def _asleep(self, entry) -> bool:
        _, t, event = entry
        return t > self._t and (event is None or not event.is_set())

    def _try_advance(self) -> bool:
        """(lock held) Jump to the earliest wake-up when no attached thread runs; True if time moved."""
        sleeping = [e for e in self._sleepers if self._asleep(e)]
        asleep_threads = {e[0] for e in sleeping}
        finished = [th for th in self._attached if th.ident is not None and not th.is_alive()]
        for th in finished:  # a thread that ended without detaching holds time no longer
            del self._attached[th]
            self._followers.discard(th)
        if any(th not in asleep_threads for th in self._attached):
            return False
        if all(e[0] in self._followers for e in sleeping):  # nobody but followers wants time to move
            return False
        self._t = max(self._t, min(e[1] for e in sleeping))
        self._cv.notify_all()
        return True

    def _sleep(self, t: float, event: threading.Event | None) -> bool:
        entry = (threading.current_thread(), float(t), event)
        with self._cv:
            self._sleepers.append(entry)
            try:
                while self._asleep(entry):
                    if not self._try_advance():
                        self._cv.wait(self._POLL_S)
                return event is not None and event.is_set()
            finally:
                self._sleepers.remove(entry)
                self._cv.notify_all()

    def sleep_until(self, t: float) -> None:
        self._sleep(t, None)

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        if event.is_set():
            return True
        return self._sleep(self._t + timeout_s, event)

    def advance(self, dt: float) -> None:
        """Move time forward by ``dt`` seconds (>= 0)."""
        if dt < 0:
            raise ValueError(f"dt must be >= 0 seconds, got {dt}")
        with self._cv:
            self._t += float(dt)
            self._cv.notify_all()


class _Device(abc.ABC):
    """Connect on ``__enter__`` (a connect that fails stops and closes what it opened); on ``__exit__`` stop
    (whatever happened) and then close."""

    def connect(self) -> None:
        """Open the connection and make the device ready to move."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop motion now. Safe to call repeatedly, from any thread, and before ``connect``. A stopped device may
        refuse motion until ``connect`` makes it ready again (the xArm does)."""

    def close(self) -> None:
        """Release the connection (after ``stop``)."""

    def __enter__(self):
        try:
            self.connect()
        except BaseException as exc:  # a with-block's exit never runs for a failed enter: release the port now
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Stop, then close, whatever happened. While an exception propagates (the fault that ended the run), a
        failure to stop or close is a note on it, never its replacement."""
        failures = []
        for step in (self.stop, self.close):
            try:
                step()
            except Exception as failure:  # noqa: BLE001 - whatever stop raised, close still runs
                failures.append((step.__name__, failure))
        if not failures:
            return
        first = failures[0][1] if exc is None else exc  # without a fault in flight, the first failure is raised
        for name, failure in failures:
            if failure is not first:
                add_note(first, f"{type(self).__name__}.{name} failed too: {failure}")
        if exc is None:
            raise first


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


class _Stream(abc.ABC):
    """A sensor read in the loop: ``start`` on ``__enter__`` (a start that fails closes what it opened),
    ``close`` on ``__exit__``."""

    def start(self) -> None:
        """Open the device and begin reading."""

    def close(self) -> None:
        """Stop reading and release the device."""

    def __enter__(self):
        try:
            self.start()
        except BaseException as exc:
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close; while an exception propagates, a failure to close is a note on it, never its replacement."""
        try:
            self.close()
        except Exception as failure:  # noqa: BLE001 - the fault in flight is the error to report
            if exc is None:
                raise
            add_note(exc, f"{type(self).__name__}.close failed too: {failure}")


class FrameSource(_Stream):
    """A camera or tactile sensor that keeps its newest frame.

    ``name`` identifies it in observations (``images/<name>`` or ``tactile/<name>``);
    ``background`` is the no-contact image (uint8 (H, W, 3)) for tactile sensors, else None.
    """

    name: str = "camera"
    background: np.ndarray | None = None

    @abc.abstractmethod
    def latest(self) -> Frame:
        """Newest frame; raises :class:`SensorError` when the source has failed or has none yet."""


class ForceSensor(_Stream):
    """What reads the force on the tactile sensor while it presses (a wrist F/T sensor, or the simulation's contact
    force); each adapter says how its ``normal_n`` is obtained. ``start`` zeroes it where the device can, with
    nothing in contact."""

    name: str = "force"

    @abc.abstractmethod
    def read(self) -> ForceSample:
        """Newest reading; raises :class:`SensorError` when the device fails."""
