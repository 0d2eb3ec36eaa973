"""The MuJoCo scene behind the hardware interfaces, so the shared control loop drives it like a robot.

``SimRobot`` owns a ``PegInHoleEnv`` and exposes ``arm`` (:class:`hardware.interfaces.Arm`),
``gripper`` (``Gripper``), ``cameras`` and ``tactile`` (``FrameSource`` by name) and ``clock``: a
virtual clock whose ``sleep_until`` advances the physics one control period per period slept,
applying the latest arm and gripper commands. The loop therefore runs as fast as the simulation
(no wall-clock waiting), deterministically, with ``ControlLoopConfig(inference="sync")``.

    with SimRobot(PegInHoleConfig(), seed=0) as robot:
        loop = ControlLoop(robot.arm, policy, gripper=robot.gripper, cameras=robot.cameras,
                           tactile=robot.tactile, limits=robot.safety_limits(), clock=robot.clock,
                           config=ControlLoopConfig(inference="sync"))
        loop.run(max_steps=120, on_step=lambda step, obs, target: robot.success)
"""

from __future__ import annotations

import math

import numpy as np

from envs.config import SENSORS, PegInHoleConfig
from envs.peg_in_hole import PegInHoleEnv
from hardware.interfaces import (
    POSE_DIM,
    Arm,
    ArmFault,
    ArmState,
    Frame,
    FrameSource,
    Gripper,
    GripperState,
    SensorError,
    VirtualClock,
)


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
        self._robot.command[:4] = t

    def stop(self) -> None:
        """Hold the measured pose (the servo target becomes where the hand is now)."""
        self._robot.command[:4] = self._robot.env.tcp_pose()


class SimGripper(Gripper):
    """The force-limited parallel gripper: ``command`` in [0, 1] (0 open, 1 closed)."""

    def __init__(self, robot: "SimRobot"):
        self._robot = robot

    def command(self, closing: float) -> None:
        c = float(closing)
        if not math.isfinite(c):
            raise ValueError(f"gripper command must be a finite number in [0, 1], got {closing!r}")
        self._robot.command[4] = c

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


class SimRobot:
    """A ``PegInHoleEnv`` episode seen through the hardware interfaces (see the module docstring).

    config: the scene; cameras and tactile streams are the ones it renders.
    seed: the episode's scene seed (``reset(seed)``).
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
        self.cameras = {c: SimFrameSource(self, c, f"images/{c}") for c in cfg.cameras}
        self.tactile = ({s: SimFrameSource(self, s, f"tactile/{s}", self.env.tactile_background(s)) for s in SENSORS}
                        if cfg.tactile else {})

    @property
    def success(self) -> bool:
        return bool(self.last_info.get("success", False))

    def advance(self) -> None:
        """One control period of physics with the current command; renders the new observation."""
        self.observation, _, _, _, self.last_info = self.env.step(self.command.copy())
        self.steps += 1
        self.frame_time = self.clock.now() + self.clock.period_s

    def safety_limits(self, max_step_m: float = 0.03, max_rotation_rad: float = 0.2):
        """``SafetyLimits`` matching the scene's workspace (per-period step limits as given)."""
        from hardware.safety import SafetyLimits

        cfg = self.env.config
        return SafetyLimits(workspace_min=cfg.workspace_low[:3], workspace_max=cfg.workspace_high[:3],
                            yaw_min=cfg.workspace_low[3], yaw_max=cfg.workspace_high[3],
                            max_step_m=max_step_m, max_rotation_rad=max_rotation_rad)

    def close(self) -> None:
        self.observation = None
        if self._own_env:
            self.env.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def run_policy_episode(policy, env_config: PegInHoleConfig | None = None, seed: int = 0, chunk_size: int = 20,
                       ensemble_k: float = 0.01, max_steps: int | None = None, env: PegInHoleEnv | None = None) -> dict:
    """Run ``policy`` (``predict_chunk(obs) -> (chunk, 5)``) for one seeded episode through ``ControlLoop``.

    Synchronous inference every step with temporal ensembling; the episode ends at success or after
    ``max_steps`` (default: the scene's ``max_steps``). ``env`` reuses an existing scene (its config
    wins). Returns success, steps, inference_ms (per call), stop_reason, safety clamp counts,
    grip_force_n and insertion_mm.
    """
    from hardware.control_loop import ControlLoop, ControlLoopConfig

    with SimRobot(env_config, seed=seed, env=env) as robot:
        cfg = robot.env.config
        loop = ControlLoop(
            robot.arm, policy, gripper=robot.gripper, cameras=robot.cameras, tactile=robot.tactile,
            limits=robot.safety_limits(), clock=robot.clock,
            config=ControlLoopConfig(rate_hz=cfg.control_hz, chunk_size=chunk_size, ensemble_k=ensemble_k,
                                     inference="sync"),
        )
        stats = loop.run(max_steps=max_steps or cfg.max_steps, on_step=lambda step, obs, target: robot.success)
        return {
            "success": robot.success, "steps": robot.steps, "seed": seed,
            "inference_ms": [t * 1e3 for t in stats.inference_s], "stop_reason": stats.stop_reason,
            "safety": stats.safety.as_dict(), "grip_force_n": robot.env.grip_force_n,
            "insertion_mm": float(robot.last_info.get("insertion_mm", 0.0)),
        }
