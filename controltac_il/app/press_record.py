"""Calibration presses recorded with the robot a lab already has: ``python -m controltac_il.calibrate record``.

The arm presses the GelSight finger against a fixed object (``mode="press"``: the TCP moves down from ``start``),
or the gripper squeezes an object standing between its fingers (``mode="squeeze"``: the closing rises from open),
along a force ramp: fast until the first contact (at most one fast step into it), then slowly until the force reads
``fz_max`` (inside the generator's validated range), then back to the start. Each press begins with
``settle_frames`` frames out of contact (the background ``calibrate`` takes per recording). Every period's tactile
frame and force go to one recording per press, in the layout ``calibrate --recordings`` reads::

    OUT/press_000/frame_00000.png ...   the sensor's frames (RGB PNG)
    OUT/press_000.csv                   t (clock s), fz (N): one row a frame
    OUT/record.json                     the plan, the start pose, the force source, the presses' peaks

The presses run through the deployment's :class:`~hardware.control_loop.ControlLoop` and its safety limits (a
:class:`PressController` is the policy). Before anything moves, a plan whose forces leave the validated range or
``ABORT_MAX_N``, or whose poses leave the setup's workspace box or step limits, is refused (ValueError naming the
field). While pressing, a force above ``fz_abort`` stops the arm (:class:`ForceLimitExceeded`), the finger is
backed out through the same loop and nothing is written. OUT is written under a temporary name and renamed when
complete.

Force readings (:class:`hardware.interfaces.ForceSensor`): a UR e-series wrist (``URForce``), an xArm F/T
(``XArmForce``) or the simulation's pad force (``envs.sim_robot.SimPadForce``). A gripper's motor current is not
offered as a force: it reads the fingers' friction and the gear's hysteresis as much as the contact, and we have
no measurement of how well it tracks a load cell; record with your load cell and ``--recordings`` instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.config import STRICT, add_note, one_line_errors
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.io import atomic_dir, write_json
from controltac_il.streams import LOOP, LOOP_STATE, tactile_key
from hardware.control_loop import ControlLoop, ControlLoopConfig
from hardware.interfaces import GRIPPER, POSE_DIM, ForceSensor, HardwareError, SensorError
from hardware.safety import SafetyLimits

ABORT_MAX_N = 15.0  # N: no plan lets the gel see more (the validated range ends at 10 N)
NO_CONTACT_N = 0.2  # N: below it a press has let go (calibrate.recordings' no-contact force)
# per mode: (fast step, slow step, largest travel) per control period: closing fraction, or metres down
STEPS = {"squeeze": (0.03, 0.015, 1.0), "press": (5e-4, 2e-4, 0.01)}
APPROACH_CLEARANCE_M = 0.05  # the start is approached from this far above it
REACHED_M = 1e-3


class ForceLimitExceeded(HardwareError):
    """The force read past the plan's ``fz_abort`` while pressing."""


@one_line_errors
@dataclass(frozen=True, config=STRICT)
class PressPlan:
    """What the presses do; validated at construction (ValueError naming the field).

    mode: "squeeze" (the gripper closes on the object) or "press" (the arm moves the finger down onto it).
    presses: how many loading ramps (one recording each). fz_max: N where a ramp turns back, inside the validated
    Fz range. fz_abort: N past which the run stops, above fz_max and at most ABORT_MAX_N. contact_n: N that counts
    as the first contact. settle_frames: frames held out of contact before each press.
    spread_m: each press starts up to this far from ``start`` (m; along the gel and in height for a squeeze,
    horizontally for a press), drawn from ``seed``, so that the presses touch different parts of the gel.
    fast_step, slow_step, max_travel: per control period and in all (closing fraction, or m); None = STEPS[mode].
    """

    mode: Literal["squeeze", "press"] = "squeeze"
    presses: int = Field(8, ge=1, le=200)
    fz_max: float = Field(9.0, ge=VALIDATED_RANGE.fz[0] + 1.0, le=VALIDATED_RANGE.fz[1], allow_inf_nan=False)
    fz_abort: float = Field(12.0, le=ABORT_MAX_N, allow_inf_nan=False)
    contact_n: float = Field(0.3, ge=NO_CONTACT_N, lt=VALIDATED_RANGE.fz[0], allow_inf_nan=False)
    settle_frames: int = Field(5, ge=2, le=100)
    spread_m: float = Field(0.003, ge=0, le=0.01, allow_inf_nan=False)
    seed: int = Field(0, ge=0)
    fast_step: float | None = Field(None, gt=0, allow_inf_nan=False)
    slow_step: float | None = Field(None, gt=0, allow_inf_nan=False)
    max_travel: float | None = Field(None, gt=0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _ordered(self):
        if self.fz_abort <= self.fz_max:
            raise ValueError(f"fz_abort={self.fz_abort} N must be above fz_max={self.fz_max} N")
        fast, slow, travel = self.steps
        if slow > fast:
            raise ValueError(f"slow_step={slow} must not exceed fast_step={fast}")
        if self.mode == "squeeze" and max(fast, travel) > 1.0:  # a closing fraction: 1 closes the gripper fully
            raise ValueError(f"{'fast_step' if fast > 1.0 else 'max_travel'}: a squeeze moves in closing fractions, "
                             f"at most 1, got {max(fast, travel):g}")
        return self

    @property
    def steps(self) -> tuple[float, float, float]:
        """(fast step, slow step, largest travel), the mode's defaults where not given."""
        d = STEPS[self.mode]
        return (self.fast_step or d[0], self.slow_step or d[1], self.max_travel or d[2])

    def steps_per_press(self) -> int:
        """Control periods one press may take at most (settle, two fast passes, the slow ramp, release)."""
        fast, slow, travel = self.steps
        return self.settle_frames + int(np.ceil(travel / slow)) + 2 * int(np.ceil(travel / fast)) + 20


def press_starts(plan: PressPlan, start: np.ndarray) -> np.ndarray:
    """(presses, 4) start poses: ``start`` moved by up to ``spread_m`` per press (the first press at ``start``)."""
    start = np.asarray(start, dtype=np.float64)
    u = np.random.default_rng(plan.seed).uniform(-1.0, 1.0, (plan.presses, 2)) * plan.spread_m
    u[0] = 0.0
    out = np.repeat(start[None], plan.presses, axis=0)
    if plan.mode == "squeeze":  # along the gel (the hand's x axis at its yaw) and in height
        out[:, 0] += u[:, 0] * np.cos(start[3])
        out[:, 1] += u[:, 0] * np.sin(start[3])
        out[:, 2] += u[:, 1]
    else:
        out[:, :2] += u
    return out


def check_plan(plan: PressPlan, limits: SafetyLimits, start: np.ndarray, open_grip: float) -> None:
    """Refuse, before anything moves, a start or a deepest pose outside the workspace box, a step the safety
    limits would cut, or a squeeze the gripper limits cannot close; ValueError naming the field."""
    start = np.asarray(start, dtype=np.float64)
    if start.shape != (POSE_DIM,) or not np.isfinite(start).all():
        raise ValueError(f"start must be 4 finite numbers [x, y, z, yaw] (m, rad), got {start.tolist()}")
    lo, hi = np.asarray(limits.workspace_min), np.asarray(limits.workspace_max)
    fast, _, travel = plan.steps
    starts = press_starts(plan, start)[:, :3]
    deepest = starts - ([0.0, 0.0, travel] if plan.mode == "press" else 0.0)
    above = start[:3] + [0.0, 0.0, APPROACH_CLEARANCE_M]
    for name, p in (("start", start[:3]), ("spread_m (a press's start)", starts), ("max_travel (the deepest press)",
                                                                                   deepest), ("start's approach", above)):
        bad = np.atleast_2d(p)[((np.atleast_2d(p) < lo) | (np.atleast_2d(p) > hi)).any(axis=1)]
        if len(bad):
            raise ValueError(f"{name}: {np.round(bad[0], 4).tolist()} m lies outside the workspace box "
                             f"{list(limits.workspace_min)}..{list(limits.workspace_max)}")
    if not limits.yaw_min <= start[3] <= limits.yaw_max:
        raise ValueError(f"start: yaw {start[3]:.3f} rad outside the limits [{limits.yaw_min}, {limits.yaw_max}]")
    if plan.mode == "press" and fast > limits.max_step_m:
        raise ValueError(f"fast_step: {fast} m per period exceeds the setup's max_step_m {limits.max_step_m}")
    if plan.mode == "squeeze" and not limits.gripper_min <= open_grip <= limits.gripper_max:
        raise ValueError(f"the open gripper {open_grip} lies outside the limits [{limits.gripper_min}, {limits.gripper_max}]")
    if plan.mode == "press" and travel > 0.03:
        raise ValueError(f"max_travel: {travel} m; a press travels at most 0.03 m past its start")


class PressController:
    """The plan as a policy for the control loop: ``(observation) -> (1, 5)`` action, reading the force each call.

    Phases: "approach" (above the start, then down to it, gripper open), "settle", "load", "release", then "approach"
    to the next press's start (``press_starts``), and "done". ``force_n`` is the reading of the last call, ``press``
    the current press.
    """

    def __init__(self, plan: PressPlan, start: np.ndarray, force: ForceSensor, open_grip: float = 0.0):
        self.plan, self.force = plan, force
        self.starts, self.open_grip = press_starts(plan, start), float(open_grip)
        self.start = self.starts[0]
        self.phase, self.press, self.force_n = "approach", 0, 0.0
        self._goal = self.start + [0.0, 0.0, APPROACH_CLEARANCE_M, 0.0]
        self._k, self._offset, self._touched = 0, 0.0, False

    def abort(self) -> None:
        """Back out: release, then done."""
        self.phase, self.press = "release", self.plan.presses - 1  # back to this press's start, then done

    def __call__(self, observation: dict) -> np.ndarray:
        self.force_n = float(self.force.read().normal_n)
        if not np.isfinite(self.force_n):  # never pressed on blind: the loop stops the arm
            raise SensorError(f"{self.force.name}: the force reads {self.force_n}")
        if self.phase == "approach":
            self._approach(np.asarray(observation[LOOP_STATE], dtype=np.float64))
        elif self.phase == "settle":
            self._k += 1
            if self._k >= self.plan.settle_frames:
                self.phase, self._offset, self._touched = "load", 0.0, False
        elif self.phase == "load":
            self._load()
        elif self.phase == "release":
            self._release()
        return self.action()[None]

    def _approach(self, qpos: np.ndarray) -> None:
        if np.linalg.norm(qpos[:3] - self._goal[:3]) < REACHED_M:
            if np.allclose(self._goal, self.start):
                self.phase, self._k = "settle", 0
            self._goal = self.start.copy()

    def _load(self) -> None:
        fast, slow, travel = self.plan.steps
        if self.force_n >= self.plan.fz_max or self._offset >= travel:
            self.phase = "release"
        else:
            self._touched = self._touched or self.force_n >= self.plan.contact_n  # from the first contact: slowly
            self._offset = min(travel, self._offset + (slow if self._touched else fast))

    def _release(self) -> None:
        self._offset = max(0.0, self._offset - self.plan.steps[0])
        if self._offset == 0.0 and self.force_n < NO_CONTACT_N:
            self.press += 1
            if self.press >= self.plan.presses:
                self.phase = "done"
            else:
                self.phase, self.start = "approach", self.starts[self.press]
                self._goal = self.start.copy()

    def action(self) -> np.ndarray:
        """[x, y, z, yaw, gripper] for the current phase and offset."""
        pose = self._goal if self.phase == "approach" else self.start
        a = np.append(pose, self.open_grip)
        if self.plan.mode == "squeeze":
            a[GRIPPER] = min(1.0, self.open_grip + self._offset)
        else:
            a[2] -= self._offset
        return a


class _Recordings:
    """One recording per press under ``root``: frames as PNG and the force log as CSV (``calibrate.recordings``).

    A closed press is written by a writer thread: PNG encoding (about 5 ms a frame, 50-80 frames a press) would
    hold the control thread past its watchdog window. ``finish`` waits for the writes and raises their error (a
    note on the run's own fault where it failed first)."""

    def __init__(self, root: Path):
        from concurrent.futures import ThreadPoolExecutor

        self.root, self.peaks = root, []
        self._frames: list[np.ndarray] = []
        self._rows: list[tuple[float, float]] = []
        self._writer, self._writes = ThreadPoolExecutor(1, thread_name_prefix="press-writer"), []

    def add(self, frame: np.ndarray, t: float, fz: float) -> None:
        self._frames.append(frame)
        self._rows.append((t, fz))

    def close_press(self, index: int) -> None:
        self.peaks.append(max(fz for _, fz in self._rows))
        self._writes.append(self._writer.submit(self._write, index, self._frames, self._rows))
        self._frames, self._rows = [], []

    def _write(self, index: int, frames: list[np.ndarray], rows: list[tuple[float, float]]) -> None:
        import cv2

        folder = self.root / f"press_{index:03d}"
        folder.mkdir()
        for k, frame in enumerate(frames):
            path = folder / f"frame_{k:05d}.png"
            if not cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)):
                raise OSError(f"{path}: the PNG could not be written")
        lines = ["t,fz", *(f"{t:.6f},{fz:.6f}" for t, fz in rows)]
        (self.root / f"press_{index:03d}.csv").write_text("\n".join(lines) + "\n")

    def finish(self, failure: BaseException | None = None) -> None:
        """Wait for every press's files. The first write's error is raised, or noted on ``failure``, the fault the
        run already ended with."""
        self._writer.shutdown(wait=True)
        errors = [w.exception() for w in self._writes if w.exception() is not None]
        if errors and failure is None:
            raise errors[0]
        if errors:
            add_note(failure, f"writing the recordings failed too: {errors[0]}")


def record_presses(setup, sensor: str, force: ForceSensor, plan: PressPlan, start, out: str | Path,
                   open_grip: float = 0.0, progress=None) -> dict:
    """Run ``plan`` on ``setup`` (``hardware.config.open_setup``'s, or ``envs.sim_robot.SimRobot``) from ``start``
    [x, y, z, yaw] and write the recordings of tactile sensor ``sensor`` to ``out`` (new); returns the summary
    also written as ``record.json``. ValueError before anything moves; :class:`ForceLimitExceeded` (nothing
    written, the finger backed out) or another HardwareError while pressing."""
    out = Path(out)
    if out.exists():
        raise ValueError(f"--out {out} exists; recordings are written to a new folder")
    if sensor not in setup.tactile:
        raise ValueError(f"--sensor {sensor!r}: the setup's tactile sensors are {sorted(setup.tactile)}")
    check_plan(plan, setup.limits, start, open_grip)
    ctrl = PressController(plan, start, force, open_grip)
    config = ControlLoopConfig(rate_hz=setup.control.rate_hz, inference="sync", chunk_size=1,
                               stale_after_periods=setup.control.stale_after_periods)
    loop = ControlLoop(setup.arm, ctrl, gripper=setup.gripper, tactile={sensor: setup.tactile[sensor]},
                       limits=setup.limits, config=config, clock=setup.clock)
    budget = plan.presses * plan.steps_per_press() + int(2 * APPROACH_CLEARANCE_M / setup.limits.max_step_m) + 100
    with atomic_dir(out) as tmp:
        recs = _Recordings(tmp)

        def on_step(step: int, obs: dict, target: np.ndarray) -> bool:
            if ctrl.force_n > plan.fz_abort:
                raise ForceLimitExceeded(f"the force read {ctrl.force_n:.2f} N, past fz_abort {plan.fz_abort} N "
                                         f"(press {ctrl.press}); the arm was stopped and the finger backed out")
            finished = ctrl.press > len(recs.peaks)  # this step's frame ends the press
            if ctrl.phase in ("settle", "load", "release") or finished:
                recs.add(obs[tactile_key(sensor, LOOP)], float(loop.clock.now()), ctrl.force_n)
            if finished:
                recs.close_press(len(recs.peaks))
                if progress is not None:
                    progress(len(recs.peaks), plan.presses)
            return ctrl.phase == "done"

        try:
            try:
                stats = loop.run(max_steps=budget, on_step=on_step)
            except ForceLimitExceeded:
                _back_out(loop, ctrl)
                raise
        except BaseException as exc:
            recs.finish(exc)
            raise
        recs.finish()
        if ctrl.phase != "done":
            raise HardwareError(f"the presses did not finish within {budget} control periods (press {ctrl.press} "
                                f"in phase {ctrl.phase}); is the object between the fingers at the start pose?")
        summary = {"plan": {**plan.__dict__, "steps": list(plan.steps)}, "start": np.asarray(start).tolist(),
                   "sensor": sensor, "force_source": force.name, "presses": len(recs.peaks),
                   "peak_fz": [round(p, 3) for p in recs.peaks], "loop": stats.summary()}
        write_json(tmp / "record.json", summary)
    return summary


def _back_out(loop: ControlLoop, ctrl: PressController) -> None:
    """After an abort: the same loop and limits take the finger back to the start, gripper open (the arm enabled
    again first: the abort stopped it, and an xArm refuses motion until then)."""
    ctrl.abort()
    loop.arm.state()  # an error the controller raised (its own collision stop) is the user's to clear, not ours
    loop.arm.connect()
    loop.run(max_steps=ctrl.plan.steps_per_press(), on_step=lambda *_: ctrl.phase == "done")

