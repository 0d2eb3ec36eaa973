"""Deploy a trained ACT: checks before motion, evaluation in the MuJoCo scene, runs on a robot.

Everything goes through ``hardware.control_loop.ControlLoop`` (10 Hz, temporal ensembling, safety
filter, stop on fault): in simulation with the MuJoCo scene behind the device interfaces, a
virtual clock (inference "sync", deterministic) through ``envs.sim_robot``, on a robot with the
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


def evaluate_in_sim(checkpoint, episodes: int = 50, seed: int = 100_000,
                    grip_force_range: tuple[float, float] | None = None, env_overrides: dict | None = None,
                    progress: bool = True, scene: str = "default") -> dict:
    """Success rate of the policy over ``episodes`` seeded scene episodes (seeds seed .. seed+episodes-1).

    Runs the robot's ControlLoop (sync inference, virtual clock, temporal ensembling, safety filter).
    grip_force_range: per-finger grip force range (N) of the test episodes; None = the scene default
        (the range the demos were collected with). env_overrides: other PegInHoleConfig fields.
    scene: "default" or "touch_critical" (``envs.config.scene_config``).
    Returns successes, episodes, success_rate, wilson95 and per-episode outcomes.
    """
    from controltac_il.pipeline import wilson_interval
    from envs.config import scene_config
    from envs.peg_in_hole import PegInHoleEnv

    from envs.sim_robot import run_policy_episode

    policy = load_policy(checkpoint)
    overrides = dict(env_overrides or {})
    if grip_force_range is not None:
        overrides["grip_force_range_n"] = tuple(grip_force_range)
    env_config = scene_config(scene, **overrides)
    check_setup(policy, env_config.cameras, ("left", "right") if env_config.tactile else ())
    cfg = policy.config
    outcomes, inference_ms, clamps = [], [], {}
    with PegInHoleEnv(env_config) as env:
        bar = tqdm(range(episodes), desc="evaluate", disable=not progress, dynamic_ncols=True)
        for i in bar:
            try:
                r = run_policy_episode(policy, seed=seed + i, chunk_size=cfg.chunk_size,
                                       ensemble_k=cfg.temporal_ensemble_coeff, env=env)
                r["error"] = None
            except Exception as exc:  # a fault ends the episode as a failure; the loop has stopped the devices
                r = {"seed": seed + i, "success": False, "steps": None, "inference_ms": [], "safety": {},
                     "error": f"{type(exc).__name__}: {exc}"}
            inference_ms.extend(r.pop("inference_ms"))
            for k, v in r.pop("safety").items():
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


__all__ = ["load_policy", "check_setup", "evaluate_in_sim", "deploy_on_robot",
           "CheckpointError"]
