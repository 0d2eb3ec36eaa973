"""One control loop for simulation and robot: observe, infer, ensemble, make safe, command.

Every period (10 Hz by default) the loop reads the arm, the gripper and the newest frame of each
camera and tactile sensor, hands the observation to the policy, takes the temporally ensembled action
for the current step, passes it through :class:`~hardware.safety.SafetyFilter` and streams it to the arm.

Inference is asynchronous by default (as in the paper): the policy runs in its own thread on the newest
observation whenever it is idle; its chunk is filed under the step of that observation, so a chunk that
arrives late contributes from where the loop already is. The loop never waits for the policy (on a
:class:`~hardware.interfaces.VirtualClock`, time does not move on while a call runs, which makes async
runs deterministic: a call lasts exactly what the policy sleeps on that clock); a policy
call that runs past ``inference_deadline_s``, or a step that no chunk covers, is a late policy.

The arm is stopped (``arm.stop()`` before anything else happens) on Ctrl-C, on any exception (device
fault, policy error, safety violation), on a stale sensor frame or missing command (watchdog) and on a
late policy; then the exception propagates with a message that says what happened. ``loop.stats`` holds
the deadline statistics of the run either way. The loop knows only the interfaces in
:mod:`hardware.interfaces`: the same code drives MuJoCo, an xArm or a UR.

Policy protocol: any callable ``policy(observation: dict[str, np.ndarray]) -> (chunk, 5)`` array of actions
``[x, y, z, yaw, gripper]`` (a function, a closure, or an object with ``__call__``). Observation keys: ``qpos`` float32 (5,) = measured ``[x, y, z, yaw, gripper]``;
``images/<camera>`` and ``tactile/<sensor>`` uint8 (H, W, 3) RGB; ``tactile_background/<sensor>`` uint8
(H, W, 3) for sensors that captured a no-contact background.
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass, field, fields
from typing import Callable, Literal, Mapping, Protocol

import numpy as np
from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass

from controltac_il.config import STRICT, add_note, one_line_errors
from controltac_il.streams import LOOP, LOOP_STATE, background_key, image_key, tactile_key
from hardware.fields import Float, Int, Problems
from hardware.interfaces import (ACTION_DIM, GRIPPER, POSE_DIM, YAW, Arm, ArmState, Clock, FrameSource, Gripper,
                                 HardwareError, WallClock)
from hardware.safety import (SafetyCounts, SafetyFilter, SafetyLimits, SafetyViolation, Watchdog, WatchdogTimeout,
                             checked_limits)
from hardware.temporal_ensembling import TemporalEnsembler


class PolicyError(HardwareError):
    """The policy raised or returned a malformed chunk."""


class PolicyLateError(HardwareError):
    """The policy missed its deadline: no action for the current step."""


class Policy(Protocol):
    """Any callable from an observation dict to an action chunk (L, 5), 1 <= L <= chunk_size."""

    def __call__(self, observation: dict[str, np.ndarray]) -> np.ndarray: ...


@one_line_errors
@pydantic_dataclass(frozen=True, config=STRICT)
class LoopTiming:
    """The loop's timing and inference settings, what a setup file states (its ``control`` section); validated at
    construction (ValueError naming the field). The chunk size and the ensembling decay are the policy's
    (:class:`ControlLoopConfig` adds them).

    rate_hz: control rate, Hz (paper: 10).
    inference: "async" = policy in its own thread, the loop never waits (robot); "sync" = policy called in
        the loop thread every ``query_every`` steps (deterministic; for simulation with a VirtualClock).
    query_every: steps between policy calls in "sync" mode (1 = every step, as with temporal ensembling).
    inference_deadline_s: a policy call running longer than this (clock seconds) is late. On a
        VirtualClock a call takes no time unless the policy sleeps on that clock.
    warmup_timeout_s: clock seconds allowed for the first chunk (model warm-up) before the arm moves.
    stale_after_periods: a sensor frame older than this many periods, or no command sent for that long,
        trips the watchdog (default two periods).
    """

    rate_hz: Float = Field(10.0, gt=0, le=1000)
    inference: Literal["async", "sync"] = "async"
    query_every: Int = Field(1, ge=1)
    inference_deadline_s: Float = Field(0.5, gt=0)
    warmup_timeout_s: Float = Field(60.0, gt=0)
    stale_after_periods: Float = Field(2.0, gt=0)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


@one_line_errors
@pydantic_dataclass(frozen=True, config=STRICT)
class ControlLoopConfig(LoopTiming):
    """Everything :class:`ControlLoop` runs on: :class:`LoopTiming` plus what the policy owns.

    chunk_size: largest action chunk the policy returns (ACT N_a = 20); a deployed ACT's own (its checkpoint).
    ensemble_k: temporal-ensembling decay, weights exp(-k * i) with i = 0 the oldest chunk (ACT: 0.01).

    With asynchronous inference, ``inference_deadline_s`` must fit in one chunk (``chunk_size`` periods):
    a call running longer leaves the loop without actions first, so a longer deadline would never fire. With
    synchronous inference, ``query_every`` is at most one chunk, else the loop runs out of actions. Checked
    here, against the chunk size the loop runs with (:meth:`for_policy` at deployment).
    """

    chunk_size: Int = Field(20, ge=1)
    ensemble_k: Float = Field(0.01, ge=0)

    @classmethod
    def for_policy(cls, timing: LoopTiming, chunk_size: int, ensemble_k: float) -> "ControlLoopConfig":
        """``timing`` (a setup's ``control`` section, or a whole config) with the policy's chunk size and
        ensembling decay; validated, so the deadline is checked against the chunk the loop will run."""
        return cls(**{f.name: getattr(timing, f.name) for f in fields(LoopTiming)}, chunk_size=chunk_size,
                   ensemble_k=ensemble_k)

    @model_validator(mode="after")
    def _within_a_chunk(self):
        """The async deadline, and the sync query interval, fit in one chunk."""
        chunk_s = self.chunk_size * self.period_s
        problems = Problems("ControlLoopConfig")
        if self.inference == "sync" and self.query_every > self.chunk_size:
            problems.add("query_every", f"more steps between policy calls than one chunk covers (chunk_size "
                         f"{self.chunk_size}): the loop would run out of actions and stop", self.query_every)
        if self.inference == "async" and self.inference_deadline_s > chunk_s + 1e-9:
            problems.add("inference_deadline_s", f"longer than one chunk of the policy (chunk_size {self.chunk_size} "
                         f"x {self.period_s:g} s = {chunk_s:g} s): asynchronous inference runs out of actions first, "
                         f"so the deadline would never fire; at most {chunk_s:g} s", self.inference_deadline_s)
        problems.raise_any()
        return self


def _percentiles(values, scale: float = 1.0) -> dict:
    if not values:
        return {"p50": None, "p99": None, "max": None}
    v = np.asarray(values, dtype=np.float64) * scale
    return {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)), "max": float(v.max())}


@dataclass
class LoopStats:
    """Per-cycle timing of one run, in the loop's clock seconds (``ControlLoop(clock=...)``): on the wall clock
    (a robot) real seconds, on a :class:`~hardware.interfaces.VirtualClock` virtual ones (a policy call then lasts
    what it sleeps on that clock, zero for a model that never does), in both inference modes alike, so that the
    statistics and the deadlines they are checked against agree and tests never depend on the wall clock. The
    wall-clock latency of a model in simulation is its caller's to measure (``controltac_il.app.deploy``).

    cycle_starts: start time of every cycle; work_s: time from a cycle's start to its command sent;
    inference_s: duration of every policy call (one that raised included), sync or async;
    deadline_misses: cycles whose work overran the period; safety: how many commands each limit changed;
    stop_reason: why the run ended.
    """

    period_s: float
    cycle_starts: list = field(default_factory=list)
    work_s: list = field(default_factory=list)
    inference_s: list = field(default_factory=list)
    deadline_misses: int = 0
    safety: SafetyCounts = field(default_factory=SafetyCounts)
    stop_reason: str = ""

    @property
    def steps(self) -> int:
        return len(self.work_s)

    def period_errors_s(self) -> np.ndarray:
        """Measured period minus the nominal one, per consecutive cycle pair (s)."""
        return np.diff(np.asarray(self.cycle_starts, dtype=np.float64)) - self.period_s

    def summary(self) -> dict:
        """Steps, |period error|, work and inference times (ms: p50, p99, max), misses, clamps, stop reason."""
        return {
            "steps": self.steps,
            "period_ms": self.period_s * 1e3,
            "period_error_ms": _percentiles(np.abs(self.period_errors_s()).tolist(), 1e3),
            "work_ms": _percentiles(self.work_s, 1e3),
            "inference_ms": _percentiles(self.inference_s, 1e3),
            "deadline_misses": self.deadline_misses,
            "safety_clamps": self.safety.as_dict(),
            "stop_reason": self.stop_reason,
        }


def _validate_chunk(chunk, chunk_size: int) -> np.ndarray:
    try:
        a = np.asarray(chunk, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PolicyError(f"policy returned {type(chunk).__name__}, not an array: {exc}") from None
    if a.ndim != 2 or a.shape[1] != ACTION_DIM or not 1 <= a.shape[0] <= chunk_size:
        raise PolicyError(
            f"policy returned shape {a.shape}, expected (L, {ACTION_DIM}) with 1 <= L <= {chunk_size} "
            "(actions [x, y, z, yaw, gripper])"
        )
    if not np.isfinite(a).all():
        raise PolicyError("policy returned NaN or inf")
    return a


class _PolicyWorker:
    """Runs the policy in a daemon thread on one submitted observation at a time.

    The thread is attached to the clock from a submission until its chunk is filed, so on a
    :class:`~hardware.interfaces.VirtualClock` time waits for the call (it takes no virtual time
    unless the policy sleeps on the clock); on the wall clock the loop never waits for it."""

    def __init__(self, policy: Policy, ensembler: TemporalEnsembler, clock: Clock, stats: LoopStats,
                 deadline_s: float):
        self.policy, self.ensembler, self.clock, self.stats = policy, ensembler, clock, stats
        self.deadline_s = deadline_s  # a call after the warm-up's (step 0) taking longer is late, its chunk unused
        self.busy_since: float | None = None
        self.busy_step: int | None = None
        self.error: BaseException | None = None
        self.chunk_ready = threading.Event()
        self._cv = threading.Condition()
        self._request: tuple[int, dict] | None = None
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="policy", daemon=True)
        self._thread.start()

    def submit(self, step: int, observation: dict) -> bool:
        """Queue ``observation`` (taken at ``step``) unless a call is in flight; True if queued."""
        with self._cv:
            if self.busy_since is not None or self.error is not None:
                return False
            self.busy_since, self.busy_step = self.clock.now(), step
            self._request = (step, observation)
            self.clock.attach(self._thread)
            self._cv.notify()
            return True

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._request is None and not self._closing:
                    self._cv.wait()
                if self._closing:
                    if self._request is not None:  # submitted, never run: release the clock
                        self.clock.detach(self._thread)
                    return
                step, obs = self._request
                self._request = None
            t0 = self.clock.now()
            try:
                chunk = _validate_chunk(self.policy(obs), self.ensembler.chunk_size)
                took = self.clock.now() - t0
                if step > 0 and took > self.deadline_s:  # ended between two polls: late all the same
                    raise PolicyLateError(f"policy inference on the observation of step {step} took {took:.3f} s, "
                                          f"past inference_deadline_s = {self.deadline_s} s")
                self.ensembler.add_chunk(step, chunk)
            except BaseException as exc:  # handed to the control thread, which stops the arm
                self.error = exc
                self.chunk_ready.set()
                self.clock.detach(self._thread)
                return
            finally:
                self.stats.inference_s.append(self.clock.now() - t0)
            with self._cv:
                self.busy_since = self.busy_step = None
            self.chunk_ready.set()
            self.clock.detach(self._thread)

    def close(self) -> None:
        with self._cv:
            self._closing = True
            self._cv.notify()


def _policy_error(exc: BaseException) -> PolicyError | PolicyLateError:
    if isinstance(exc, (PolicyError, PolicyLateError)):  # the loop's own verdicts on the policy, as they are
        return exc
    err = PolicyError(f"policy raised {type(exc).__name__}: {exc}")
    err.__cause__ = exc
    return err


class ControlLoop:
    """Drive ``arm`` (and ``gripper``) with ``policy`` at a fixed rate; see the module docstring.

    arm, gripper: connected devices (the caller opens and closes them; the loop only stops them).
    cameras, tactile: frame sources by name -> observation keys ``images/<name>``, ``tactile/<name>``.
    limits: safety limits between policy and arm (required: no box is assumed). config: timing and inference
        settings.
    clock: time source; ``WallClock()`` for a robot, a :class:`~hardware.interfaces.VirtualClock` shared
        with a simulated robot's frame sources to run faster than real time.
    watchdog_thread: also check the watchdog from its own thread, which stops the arm while the control
        thread hangs in a device call (default: on a real-time clock only; tests turn it on with a VirtualClock).
    """

    def __init__(
        self,
        arm: Arm,
        policy: Policy,
        *,
        gripper: Gripper | None = None,
        cameras: Mapping[str, FrameSource] | None = None,
        tactile: Mapping[str, FrameSource] | None = None,
        limits: SafetyLimits,
        config: ControlLoopConfig | None = None,
        clock: Clock | None = None,
        watchdog_thread: bool | None = None,
    ):
        self.arm, self.policy, self.gripper = arm, policy, gripper
        self.cameras, self.tactile = dict(cameras or {}), dict(tactile or {})
        self.limits = checked_limits(limits)
        self.config = config or ControlLoopConfig()
        self.clock = clock or WallClock()
        self.watchdog_thread = self.clock.realtime if watchdog_thread is None else watchdog_thread
        self.stats = LoopStats(self.config.period_s)
        self._device_lock = threading.Lock()
        self._last_grip = 0.0
        self._trip_problems: list[str] = []

    # -- observation -------------------------------------------------------------------------
    def _observe(self, watchdog: Watchdog) -> tuple[dict[str, np.ndarray], ArmState]:
        """Observation dict and the arm state it was built from; feeds frame timestamps to the watchdog."""
        state = self.arm.state()
        grip = self.gripper.state().position if self.gripper is not None else self._last_grip
        if not np.isfinite(grip):  # else the policy's NaN output would be blamed
            raise SafetyViolation(f"measured gripper position must be a finite number, got {grip!r}")
        obs = {LOOP_STATE: np.append(np.asarray(state.pose, dtype=np.float32), np.float32(grip))}
        for key_of, sources in ((image_key, self.cameras), (tactile_key, self.tactile)):
            for name, src in sources.items():
                frame = src.latest()
                key = key_of(name, LOOP)
                watchdog.feed(f"frame:{key}", frame.timestamp)
                obs[key] = frame.image
                if key_of is tactile_key and src.background is not None:
                    obs[background_key(name, LOOP)] = src.background
        return obs, state

    # -- stopping ----------------------------------------------------------------------------
    def _stop_devices(self) -> list[str]:
        """Stop the arm first, then the gripper; return what failed while stopping."""
        problems = []
        for name, dev in (("arm", self.arm), ("gripper", self.gripper)):
            if dev is None:
                continue
            try:
                dev.stop()
            except Exception as exc:  # keep stopping the rest; reported with the original error
                problems.append(f"{name}.stop() failed: {type(exc).__name__}: {exc}")
        return problems

    def _watchdog_trip(self) -> None:
        # called from the watchdog thread when the control thread went silent: stop now, without the lock; a
        # failure is noted on the fault the control thread then raises
        try:
            self.arm.stop()
        except Exception as exc:  # noqa: BLE001 - whatever the arm raised, the watchdog thread must not die
            self._trip_problems.append(f"the watchdog's arm.stop() failed: {type(exc).__name__}: {exc}")

    # -- main loop ---------------------------------------------------------------------------
    def run(self, max_steps: int | None = None,
            on_step: Callable[[int, dict, np.ndarray], bool] | None = None) -> LoopStats:
        """Run until ``max_steps`` steps, ``on_step(step, observation, target)`` returns True, or a fault.

        The arm is stopped at the end in every case. Returns :class:`LoopStats` (also ``self.stats``).
        """
        if max_steps is not None and (not isinstance(max_steps, int) or max_steps < 1):
            raise ValueError(f"max_steps must be a positive integer or None, got {max_steps!r}")
        cfg, clock = self.config, self.clock
        self.stats = stats = LoopStats(cfg.period_s)
        self._trip_problems = []
        ensembler = TemporalEnsembler(cfg.chunk_size, ACTION_DIM, cfg.ensemble_k, angle_dims=(YAW,))
        safety = SafetyFilter(self.limits)
        stats.safety = safety.counts
        watchdog = Watchdog(cfg.stale_after_periods * cfg.period_s, clock)
        worker: _PolicyWorker | None = None
        clock.attach()  # on a virtual clock, time moves only while this thread sleeps on it
        try:
            obs, state = self._observe(watchdog)
            safety.reset(state.pose)
            if cfg.inference == "async":
                worker = _PolicyWorker(self.policy, ensembler, clock, stats, cfg.inference_deadline_s)
                worker.submit(0, obs)
                if not clock.wait(worker.chunk_ready, cfg.warmup_timeout_s):
                    raise PolicyLateError(f"no first chunk within warmup_timeout_s = {cfg.warmup_timeout_s} s")
                if worker.error is not None:
                    raise _policy_error(worker.error)
            else:
                self._predict_sync(0, obs, ensembler, stats, deadline=cfg.warmup_timeout_s)
            self._cycles(max_steps, on_step, ensembler, safety, watchdog, worker)
        except BaseException as exc:
            problems = self._stop_devices()
            watchdog.stop()  # joined: a stop the watchdog thread was still making has failed or not by now
            problems = self._trip_problems + problems
            stats.stop_reason = (
                "Ctrl-C" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
            )
            for p in problems:
                add_note(exc, p)
            raise
        else:
            problems = self._stop_devices()
            if problems:
                raise HardwareError("; ".join(problems))
        finally:
            watchdog.stop()
            if worker is not None:
                worker.close()
            clock.detach()
        return stats

    def _cycles(self, max_steps, on_step, ensembler: TemporalEnsembler, safety: SafetyFilter, watchdog: Watchdog,
                worker: _PolicyWorker | None) -> None:
        """The periodic part of :meth:`run`: observe, infer, act, command, wait for the next period."""
        cfg, clock, stats = self.config, self.clock, self.stats
        next_start = clock.now()
        steps = range(max_steps) if max_steps is not None else itertools.count()
        for step in steps:
            start = clock.now()
            stats.cycle_starts.append(start)
            obs, state = self._observe(watchdog)  # fresh at step 0 too: the warm-up may have taken seconds
            if step == 0:  # the first command is one step from where the arm is now, not before the warm-up
                safety.reset(state.pose)
                watchdog.feed("command", start)  # from here a silent control thread is a fault, the first command's too
                if self.watchdog_thread:  # started on fresh frames: those fed before the warm-up are its age old
                    watchdog.start(self._watchdog_trip)
            else:
                safety.check_state(state.pose)
            watchdog.check(start)
            if worker is not None:
                self._poll_worker(worker, step, obs, start)
            elif step > 0 and step % cfg.query_every == 0:
                self._predict_sync(step, obs, ensembler, stats, deadline=cfg.inference_deadline_s)
            target = self._action(ensembler, step, safety)
            self._command(target, watchdog)
            stats.work_s.append(clock.now() - start)
            if on_step is not None and on_step(step, obs, target):
                stats.stop_reason = f"on_step ended the run at step {step}"
                return
            next_start += cfg.period_s
            now = clock.now()
            if now > next_start:
                stats.deadline_misses += 1
                next_start = now
            clock.sleep_until(next_start)
        stats.stop_reason = f"finished {max_steps} steps"

    def _poll_worker(self, worker: _PolicyWorker, step: int, obs: dict, now: float) -> None:
        if worker.error is not None:
            raise _policy_error(worker.error)
        busy_since, busy_step = worker.busy_since, worker.busy_step
        if busy_since is None:
            if step > 0:
                worker.submit(step, obs)
        elif now - busy_since > self.config.inference_deadline_s:
            raise PolicyLateError(
                f"policy inference on the observation of step {busy_step} has run {now - busy_since:.3f} s, "
                f"past inference_deadline_s = {self.config.inference_deadline_s} s"
            )

    def _predict_sync(self, step: int, obs: dict, ensembler: TemporalEnsembler, stats: LoopStats,
                      deadline: float) -> None:
        """Call the policy in the loop thread; its duration (clock seconds: a virtual clock counts only what the
        policy spends sleeping on it) goes to ``stats.inference_s`` and is checked against ``deadline``."""
        t0 = self.clock.now()
        try:
            chunk = _validate_chunk(self.policy(obs), ensembler.chunk_size)
        except Exception as exc:
            raise _policy_error(exc) from exc
        finally:
            stats.inference_s.append(self.clock.now() - t0)
        elapsed = stats.inference_s[-1]
        if elapsed > deadline:
            raise PolicyLateError(f"policy inference at step {step} took {elapsed:.3f} s, past its deadline of {deadline} s")
        ensembler.add_chunk(step, chunk)

    def _action(self, ensembler: TemporalEnsembler, step: int, safety: SafetyFilter) -> np.ndarray:
        try:
            action = ensembler.action(step)
        except LookupError:
            raise PolicyLateError(
                f"no action for step {step}: every chunk predicted so far has run out "
                f"(chunk_size {self.config.chunk_size}); the policy is late"
            ) from None
        return safety(action)

    def _command(self, target: np.ndarray, watchdog: Watchdog) -> None:
        with self._device_lock:
            if watchdog.tripped is not None:
                raise WatchdogTimeout(watchdog.tripped)
            self.arm.servo(target[:POSE_DIM])
            if watchdog.tripped is not None:  # tripped while the arm's command was in flight: no gripper after it
                raise WatchdogTimeout(watchdog.tripped)
            if self.gripper is not None:
                self.gripper.command(float(target[GRIPPER]))
            self._last_grip = float(target[GRIPPER])
            if watchdog.tripped is not None:  # tripped while the command was in flight: stop again, now
                raise WatchdogTimeout(watchdog.tripped)
        watchdog.feed("command", self.clock.now())
