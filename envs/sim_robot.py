"""The MuJoCo scene as a robot setup, so the shared control loop drives it like an xArm or a UR.

``SimRobot`` owns a ``PegInHoleEnv`` episode and exposes what ``hardware.config.open_setup`` gives for
a real robot: ``arm`` (:class:`hardware.interfaces.Arm`), ``gripper``, ``cameras`` and ``tactile``
(``FrameSource`` by name), ``limits`` (the scene's workspace as SafetyLimits) and ``control``
(synchronous inference at the scene's rate), plus ``clock``: a virtual clock whose ``sleep_until``
advances the physics one control period per period slept, applying the latest arm and gripper
commands. The loop therefore runs as fast as the simulation (no wall-clock waiting), deterministically.

    with SimRobot(PegInHoleConfig(), seed=0) as robot:
        loop = ControlLoop(robot.arm, policy, gripper=robot.gripper, cameras=robot.cameras,
                           tactile=robot.tactile, limits=robot.limits, clock=robot.clock, config=robot.control)
        loop.run(max_steps=120, on_step=lambda step, obs, target: robot.success)
"""

from __future__ import annotations

import math

import numpy as np

from controltac_il.streams import LOOP, force_key, image_key, tactile_key
from envs.config import SENSORS, PegInHoleConfig
from envs.expert import wrap_half_turn
from envs.peg_in_hole import PegInHoleEnv
from hardware.control_loop import ControlLoopConfig
from hardware.interfaces import (
    GRIPPER,
    POSE_DIM,
    Arm,
    ArmFault,
    ArmState,
    ForceSample,
    ForceSensor,
    Frame,
    FrameSource,
    Gripper,
    GripperState,
    SensorError,
    VirtualClock,
)
from hardware.safety import SafetyLimits

MAX_STEP_M = 0.03  # per-period translation limit of the simulated arm (the scene's expert moves <= 2 cm)
MAX_ROTATION_RAD = 0.2  # per-period yaw limit


class SimClock(VirtualClock):
    """Simulated time: sleeping until ``t`` steps the scene once per control period up to ``t``."""

    def __init__(self, robot: "SimRobot"):
        super().__init__(0.0)
        self._robot = robot
        self.period_s = 1.0 / robot.env.config.control_hz

    def sleep_until(self, t: float) -> None:
        # a period that ends within 1 µs of t counts as reached (float sums of 0.1 s drift)
        while self.now() + 1e-6 < float(t):
            self._robot.advance()
            self.advance(self.period_s)


class SimArm(Arm):
    """End-effector of the simulated gripper: ``servo`` sets the target of the next physics period."""

    def __init__(self, robot: "SimRobot"):
        self._robot = robot

    def state(self) -> ArmState:
        return ArmState(self._robot.env.tcp_pose(), self._robot.clock.now())

    def servo(self, target) -> None:
        t = np.asarray(target, dtype=np.float64)
        if t.shape != (POSE_DIM,) or not np.isfinite(t).all():
            raise ArmFault(f"sim arm: target must be 4 finite numbers [x, y, z, yaw], got {target!r}")
        self._robot.command[:POSE_DIM] = t

    def stop(self) -> None:
        """Hold the measured pose (the servo target becomes where the hand is now)."""
        self._robot.command[:POSE_DIM] = self._robot.env.tcp_pose()


class SimGripper(Gripper):
    """The force-limited parallel gripper: ``command`` in [0, 1] (0 open, 1 closed)."""

    def __init__(self, robot: "SimRobot"):
        self._robot = robot

    def command(self, closing: float) -> None:
        c = float(closing)
        if not math.isfinite(c):
            raise ValueError(f"gripper command must be a finite number in [0, 1], got {closing!r}")
        self._robot.command[GRIPPER] = c

    def state(self) -> GripperState:
        return GripperState(self._robot.env.gripper_closure(), self._robot.clock.now())

    def stop(self) -> None:
        """A gripper holds what it grasps; stopping keeps the last command."""


class SimFrameSource(FrameSource):
    """Newest rendering of one camera or tactile sensor (``key`` in the env's observation)."""

    def __init__(self, robot: "SimRobot", name: str, key: str, background: np.ndarray | None = None):
        self._robot, self.name, self._key, self.background = robot, name, key, background

    def latest(self) -> Frame:
        obs = self._robot.observation
        if obs is None or self._key not in obs:
            raise SensorError(f"sim {self._key}: no frame (the robot is closed or the stream is not rendered)")
        return Frame(obs[self._key], self._robot.frame_time, self._robot.steps)


class SimPadForce(ForceSensor):
    """The contact force on one gel, as the simulation knows it: ``normal_n`` = the pad's Fz in its sensor frame
    (N, the tactile frames' own label), at the newest frame's time."""

    def __init__(self, robot: "SimRobot", sensor: str):
        self._robot, self.name = robot, f"sim_{sensor}_pad"
        self._sensor = sensor

    def read(self) -> ForceSample:
        obs = self._robot.observation
        if obs is None:
            raise SensorError(f"sim {self.name}: no reading (the robot is closed)")
        return ForceSample(float(obs[force_key(self._sensor, LOOP)][2]), self._robot.frame_time)


class SimRobot:
    """A ``PegInHoleEnv`` episode seen through the hardware interfaces (see the module docstring).

    config: the scene; cameras and tactile streams are the ones it renders.
    seed: the episode's scene seed (``reset(seed)``).
    limits: the scene's workspace with per-period limits MAX_STEP_M / MAX_ROTATION_RAD.
    control: ``ControlLoopConfig(rate_hz=<scene's control_hz>, inference="sync")``.
    force: a :class:`SimPadForce` per gel (``python -m controltac_il.calibrate record --sim``).
    After each period: ``last_info`` (the env's info dict), ``success``, ``steps``.
    """

    def __init__(self, config: PegInHoleConfig | None = None, seed: int = 0, env: PegInHoleEnv | None = None):
        self.env = env or PegInHoleEnv(config)
        self._own_env = env is None
        self.clock = SimClock(self)
        self.observation, self.last_info = self.env.reset(seed=seed)
        self.frame_time = self.clock.now()
        self.steps = 0
        self.command = self.env.command  # hold what the scene starts with (a held peg stays held)
        self.arm, self.gripper = SimArm(self), SimGripper(self)
        cfg = self.env.config
        self.cameras = {c: SimFrameSource(self, c, image_key(c, LOOP)) for c in cfg.cameras}
        self.tactile = ({s: SimFrameSource(self, s, tactile_key(s, LOOP), self.env.tactile_background(s))
                         for s in SENSORS} if cfg.tactile else {})
        self.limits = SafetyLimits(workspace_min=cfg.workspace_low[:3], workspace_max=cfg.workspace_high[:3],
                                   yaw_min=cfg.workspace_low[3], yaw_max=cfg.workspace_high[3],
                                   max_step_m=MAX_STEP_M, max_rotation_rad=MAX_ROTATION_RAD)
        self.control = ControlLoopConfig(rate_hz=cfg.control_hz, inference="sync")
        self.force = {s: SimPadForce(self, s) for s in SENSORS}

    def squeeze_pose(self, depth_m: float = 0.018) -> np.ndarray:
        """[x, y, z, yaw] (m, rad) that puts the standing peg between the open fingers, the TCP ``depth_m``
        below its top, the gels square to it: where calibration presses squeeze it."""
        pos, rot = self.env.peg_pose()
        yaw = wrap_half_turn(math.atan2(rot[1, 0], rot[0, 0]))
        return np.array([pos[0], pos[1], pos[2] + self.env.peg_half_length_m - depth_m, yaw])

    @property
    def success(self) -> bool:
        return bool(self.last_info.get("success", False))

    def advance(self) -> None:
        """One control period of physics with the current command; renders the new observation."""
        self.observation, _, _, _, self.last_info = self.env.step(self.command.copy())
        self.steps += 1
        self.frame_time = self.clock.now() + self.clock.period_s

    def close(self) -> None:
        self.observation = None
        if self._own_env:
            self.env.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

