"""Deploy a trained ACT: checks before motion, evaluation in the MuJoCo scene, runs on a robot.

Everything goes through ``hardware.control_loop.ControlLoop`` (10 Hz, temporal ensembling, safety
filter, stop on fault): in simulation with the MuJoCo scene behind the device interfaces, a
virtual clock (inference "sync", deterministic) through :class:`SimScene`, on a robot with the
adapters named in a setup YAML.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from policies.act.checkpoint import CheckpointError
from policies.act.policy import ACTPolicy
from policies.act.training import resolve_checkpoint


def load_policy(checkpoint: str | Path | ACTPolicy, device: str = "cpu") -> ACTPolicy:
    """An :class:`ACTPolicy` from a checkpoint folder or a training output folder (best, else last)."""
    if isinstance(checkpoint, ACTPolicy):
        return checkpoint
    return ACTPolicy.from_pretrained(resolve_checkpoint(checkpoint), device=device)


def check_setup(policy: ACTPolicy, cameras, tactile, action_dim: int = 5, state_dim: int = 5) -> None:
    """Raise ValueError (before anything moves) when the robot set-up lacks what the policy expects."""
    cfg = policy.config
    missing = [f"camera {c!r}" for c in cfg.camera_names if c not in cameras]
    missing += [f"tactile sensor {s!r}" for s in cfg.tactile_names if s not in tactile]
    if missing:
        raise ValueError(f"the set-up has no {', '.join(missing)} that the checkpoint expects "
                         f"(set-up: cameras {sorted(cameras)}, tactile {sorted(tactile)})")
    if cfg.action_dim != action_dim:
        raise ValueError(f"the checkpoint predicts actions of dimension {cfg.action_dim}; the robot takes {action_dim} "
                         f"([x, y, z, yaw, gripper])")
    if cfg.state_dim != state_dim:
        raise ValueError(f"the checkpoint reads qpos of dimension {cfg.state_dim}; the robot gives {state_dim}")


class SimScene:
    """One ``PegInHoleEnv`` behind the hardware interfaces, for the control loop in simulation.

    ``arm``, ``gripper``, ``cameras`` and ``tactile`` implement ``hardware.interfaces``; the physics
    advances by one control step when a cycle's command is complete (the gripper command follows the
    arm target in every cycle), so the loop's target [x, y, z, yaw, gripper] becomes one ``env.step``.
    Frames are stamped with the shared virtual clock at the step that rendered them.
    """

    def __init__(self, env, clock) -> None:
        from hardware.interfaces import Arm, ArmState, Frame, FrameSource, Gripper, GripperState

        scene = self
        self.env, self.clock = env, clock
        self.obs: dict = {}
        self.stamp, self.index, self.success = 0.0, 0, False
        self._pose = np.zeros(4)

        class _Arm(Arm):
            def state(self):
                return ArmState(scene.env.tcp_pose(), scene.clock.now())

            def servo(self, target):
                scene._pose = np.asarray(target, dtype=np.float64).copy()

            def stop(self):
                pass  # the floating hand holds its last target; no further steps are taken

        class _Gripper(Gripper):
            def command(self, closing):
                scene._advance(float(closing))

            def state(self):
                return GripperState(float(scene.env.gripper_closure()), scene.clock.now())

            def stop(self):
                pass

        class _Frames(FrameSource):
            def __init__(self, key, background=None):
                self.name, self.key, self.background = key.split("/")[1], key, background

            def latest(self):
                return Frame(scene.obs[self.key], scene.stamp, scene.index)

        self.arm, self.gripper = _Arm(), _Gripper()
        self.cameras = {c: _Frames(f"images/{c}") for c in env.config.cameras}
        self.tactile = ({s: _Frames(f"tactile/{s}", env.tactile_background(s)) for s in ("left", "right")}
                        if env.config.tactile else {})

    def reset(self, seed: int) -> None:
        self.obs, _ = self.env.reset(seed=seed)
        self.stamp, self.index, self.success = self.clock.now(), self.index + 1, False
        self._pose = self.env.tcp_pose()

    def _advance(self, grip: float) -> None:
        self.obs, _, _, _, info = self.env.step(np.append(self._pose, grip))
        self.stamp, self.index = self.clock.now(), self.index + 1
        self.success = bool(info["success"])

    def limits(self):
        """Safety limits of the scene: its workspace box, steps a little above the expert's largest."""
        from hardware.safety import SafetyLimits

        cfg = self.env.config
        return SafetyLimits(workspace_min=tuple(cfg.workspace_low[:3]), workspace_max=tuple(cfg.workspace_high[:3]),
                            yaw_min=max(cfg.workspace_low[3], -np.pi), yaw_max=min(cfg.workspace_high[3], np.pi),
                            max_step_m=0.03, max_rotation_rad=0.25, state_tolerance_m=0.03)


def run_sim_episode(policy: ACTPolicy, scene: SimScene, seed: int) -> dict:
    """One seeded episode through the control loop; ends at success or after the scene's max_steps."""
    from hardware.control_loop import ControlLoop, ControlLoopConfig

    scene.reset(seed)
    cfg = policy.config
    loop = ControlLoop(scene.arm, policy, gripper=scene.gripper, cameras=scene.cameras, tactile=scene.tactile,
                       limits=scene.limits(), clock=scene.clock,
                       config=ControlLoopConfig(rate_hz=scene.env.config.control_hz, chunk_size=cfg.chunk_size,
                                                ensemble_k=cfg.temporal_ensemble_coeff, inference="sync"))
    error = None
    try:
        stats = loop.run(max_steps=scene.env.config.max_steps, on_step=lambda step, obs, target: scene.success)
    except Exception as exc:  # a fault ends the episode as a failure; the loop has stopped the devices
        stats, error = loop.stats, f"{type(exc).__name__}: {exc}"
    return {"seed": seed, "success": scene.success, "steps": stats.steps, "error": error,
            "inference_ms": [t * 1e3 for t in stats.inference_s], "safety_clamps": stats.safety.as_dict()}


def evaluate_in_sim(checkpoint, episodes: int = 50, seed: int = 100_000,
                    grip_force_range: tuple[float, float] | None = None, env_overrides: dict | None = None,
                    progress: bool = True) -> dict:
    """Success rate of the policy over ``episodes`` seeded scene episodes (seeds seed .. seed+episodes-1).

    Runs the robot's ControlLoop (sync inference, virtual clock, temporal ensembling, safety filter).
    grip_force_range: per-finger grip force range (N) of the test episodes; None = the scene default
        (the range the demos were collected with). env_overrides: other PegInHoleConfig fields.
    Returns successes, episodes, success_rate, wilson95 and per-episode outcomes.
    """
    from controltac_il.pipeline import wilson_interval
    from envs.config import PegInHoleConfig
    from envs.peg_in_hole import PegInHoleEnv
    from hardware.interfaces import VirtualClock

    policy = load_policy(checkpoint)
    overrides = dict(env_overrides or {})
    if grip_force_range is not None:
        overrides["grip_force_range_n"] = tuple(grip_force_range)
    env_config = PegInHoleConfig(**overrides)
    check_setup(policy, env_config.cameras, ("left", "right") if env_config.tactile else ())
    outcomes, inference_ms, clamps = [], [], {}
    with PegInHoleEnv(env_config) as env:
        scene = SimScene(env, VirtualClock())
        bar = tqdm(range(episodes), desc="evaluate", disable=not progress, dynamic_ncols=True)
        for i in bar:
            r = run_sim_episode(policy, scene, seed + i)
            inference_ms.extend(r.pop("inference_ms"))
            for k, v in r.pop("safety_clamps").items():
                clamps[k] = clamps.get(k, 0) + v
            outcomes.append(r)
            bar.set_postfix(success=f"{sum(o['success'] for o in outcomes)}/{len(outcomes)}")
    k = sum(o["success"] for o in outcomes)
    lo, hi = wilson_interval(k, episodes)
    return {"successes": k, "episodes": episodes, "success_rate": k / episodes if episodes else 0.0,
            "wilson95": [lo, hi], "grip_force_range_n": list(env_config.grip_force_range_n),
            "inference_ms_p50": float(np.median(inference_ms)) if inference_ms else None,
            "safety_clamps": clamps, "errors": sum(o["error"] is not None for o in outcomes), "outcomes": outcomes}


def deploy_on_robot(kind: str, checkpoint, setup_yaml: str | Path, max_steps: int | None = None) -> dict:
    """Run the policy on the robot described by ``setup_yaml`` (``hardware/configs/*.yaml``).

    The checkpoint and the set-up are checked against each other before any device is connected;
    the loop stops the arm on Ctrl-C, a fault, a stale frame or a late policy. Returns the loop's
    deadline statistics.
    """
    from hardware.config import load_setup, open_setup
    from hardware.control_loop import ControlLoop

    setup_cfg = load_setup(setup_yaml)
    if setup_cfg.robot.type != kind:
        raise ValueError(f"--robot {kind}, but {setup_yaml} describes robot.type {setup_cfg.robot.type!r}")
    policy = load_policy(checkpoint)
    check_setup(policy, setup_cfg.cameras, setup_cfg.tactile)
    control = replace(setup_cfg.control, chunk_size=policy.config.chunk_size)
    with open_setup(setup_cfg) as setup:
        loop = ControlLoop(setup.arm, policy, gripper=setup.gripper, cameras=setup.cameras, tactile=setup.tactile,
                           limits=setup.limits, config=control)
        stats = loop.run(max_steps=max_steps)
    return stats.summary()


__all__ = ["load_policy", "check_setup", "SimScene", "run_sim_episode", "evaluate_in_sim", "deploy_on_robot",
           "CheckpointError"]
