"""Deploy a trained ACT through the robot's control loop: one ``deploy(setup, policy)`` for every robot.

A *setup* is anything with ``arm``, ``gripper``, ``cameras``, ``tactile`` (FrameSource by name),
``limits`` (SafetyLimits), ``control`` (LoopTiming, or a ControlLoopConfig) and ``clock``: ``hardware.config.open_setup``
gives one for an xArm or a UR, ``envs.sim_robot.SimRobot`` one for the MuJoCo scene (virtual clock,
synchronous inference, deterministic). The policy owns the chunk size and the temporal-ensembling
coefficient (its checkpoint; a setup file may not state them); the setup gives the rate, the inference mode
and the deadlines, and the inference deadline is checked against the policy's chunk when the loop is built
(for a robot before anything connects).

Times: the loop's statistics (``LoopStats``) are in its clock's seconds, virtual in the simulation; the
simulated evaluation's ``inference_ms`` is the model's wall-clock latency, measured here around each call.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from controltac_il.cli import RunFault, tty_only
from controltac_il.config import one_line
from controltac_il.metrics import wilson_interval
from envs.config import EVAL_SEED, SENSORS, scene_config
from hardware.config import load_setup, loop_config, open_setup
from hardware.control_loop import ControlLoop, ControlLoopConfig, LoopStats
from hardware.interfaces import ACTION_DIM, ACTION_NAMES, HardwareError  # noqa: F401 - HardwareError for the CLI
from policies.act.policy import ACTPolicy
from policies.act.training import resolve_checkpoint

if TYPE_CHECKING:
    from envs.peg_in_hole import PegInHoleEnv


def load_policy(checkpoint: str | Path | ACTPolicy, device: str = "cpu") -> ACTPolicy:
    """An :class:`ACTPolicy` from a checkpoint folder or a training output folder (best, else last)."""
    if isinstance(checkpoint, ACTPolicy):
        return checkpoint
    return ACTPolicy.from_pretrained(resolve_checkpoint(checkpoint), device=device)


def check_setup(policy: ACTPolicy, cameras, tactile) -> None:
    """Raise ValueError (before anything moves) when the set-up lacks what the policy expects."""
    cfg = policy.config
    missing = [f"camera {c!r}" for c in cfg.camera_names if c not in cameras]
    missing += [f"tactile sensor {s!r}" for s in cfg.tactile_names if s not in tactile]
    if missing:
        raise ValueError(f"the set-up has no {', '.join(missing)} that the checkpoint expects "
                         f"(set-up: cameras {sorted(cameras)}, tactile {sorted(tactile)})")
    for name, dim in (("action_dim", cfg.action_dim), ("state_dim", cfg.state_dim)):
        if dim != ACTION_DIM:
            raise ValueError(f"the checkpoint's {name} is {dim}; the robot's actions and qpos are "
                             f"[{', '.join(ACTION_NAMES)}] ({ACTION_DIM})")


def deploy(setup, policy: ACTPolicy, max_steps: int | None = None, stop_when=None) -> LoopStats:
    """Run ``policy`` on ``setup`` through :class:`ControlLoop` until ``max_steps`` or ``stop_when()``.

    The checkpoint and the set-up are checked against each other before anything moves (the inference
    deadline against the policy's chunk too); the loop stops the arm on Ctrl-C, a fault, a stale frame or a
    late policy. Returns the loop's statistics (clock seconds).
    """
    check_setup(policy, setup.cameras, setup.tactile)
    config = ControlLoopConfig.for_policy(setup.control, policy.config.chunk_size,
                                          policy.config.temporal_ensemble_coeff)
    loop = ControlLoop(setup.arm, policy, gripper=setup.gripper, cameras=setup.cameras, tactile=setup.tactile,
                       limits=setup.limits, clock=setup.clock, config=config)
    on_step = (lambda step, obs, target: stop_when()) if stop_when is not None else None
    return loop.run(max_steps=max_steps, on_step=on_step)


class WallTimed:
    """``policy`` with the wall-clock duration of every call in ``wall_s`` (the simulation's clock is virtual,
    so the loop's own ``inference_s`` does not see the model's latency); ``config`` is the policy's."""

    def __init__(self, policy: ACTPolicy):
        self.policy, self.config, self.wall_s = policy, policy.config, []

    def __call__(self, observation):
        t0 = time.perf_counter()
        try:
            return self.policy(observation)
        finally:
            self.wall_s.append(time.perf_counter() - t0)


def run_sim_episode(policy: ACTPolicy, env: PegInHoleEnv, seed: int) -> dict:
    """One seeded scene episode through :func:`deploy`; ends at success or after the scene's max_steps.

    Returns success, steps, seed, inference_ms (wall-clock ms per policy call), stop_reason, safety clamp
    counts, grip_force_n and insertion_mm.
    """
    from envs.sim_robot import SimRobot  # the [sim] extra, needed only here: a robot deploys without MuJoCo

    timed = WallTimed(policy)
    with SimRobot(seed=seed, env=env) as robot:
        stats = deploy(robot, timed, max_steps=env.config.max_steps, stop_when=lambda: robot.success)
        return {"success": robot.success, "steps": robot.steps, "seed": seed,
                "inference_ms": [t * 1e3 for t in timed.wall_s], "stop_reason": stats.stop_reason,
                "safety": stats.safety.as_dict(), "grip_force_n": env.grip_force_n,
                "insertion_mm": float(robot.last_info.get("insertion_mm", 0.0))}


class EvaluationError(RunFault):
    """Episodes raised during an evaluation: a crash is not a failed episode, so no success rate is given.

    ``result``: the evaluation as far as it went (``errors`` lists each raising episode's seed and one line)."""

    def __init__(self, result: dict, where: str = "evaluation"):
        errors = result["errors"]
        first = errors[0]
        super().__init__(f"{where}: {len(errors)} of {result['episodes']} episodes raised and were not counted "
                         f"(first: seed {first['seed']}: {first['error']})")
        self.result, self.where = result, where

    def __reduce__(self):  # across a process pool: rebuilt from what it was made of
        return type(self), (self.result, self.where)


def _episode(policy: ACTPolicy, env: PegInHoleEnv, seed: int) -> dict:
    """``run_sim_episode``, with an exception turned into ``error`` (one line) and ``success`` None: not a failure."""
    try:
        return {**run_sim_episode(policy, env, seed), "error": None}
    except Exception as exc:  # noqa: BLE001 - reported, never counted; the loop has stopped the devices
        return {"seed": seed, "success": None, "steps": None, "inference_ms": [], "safety": {},
                "error": f"{type(exc).__name__}: {one_line(exc)}"}


def evaluate_in_sim(checkpoint, episodes: int = 50, seed: int = EVAL_SEED,
                    grip_force_range: tuple[float, float] | None = None, env_overrides: dict | None = None,
                    progress: bool = True, scene: str = "default", on_error: str = "raise",
                    label: str = "evaluation") -> dict:
    """Success rate of the policy over ``episodes`` seeded scene episodes (seeds seed .. seed+episodes-1).

    grip_force_range: per-finger grip force range (N) of the test episodes; None = the scene's (the
        range the demos were collected with). env_overrides: other PegInHoleConfig fields.
    scene: "default" or "touch_critical" (``envs.config.scene_config``).
    on_error: an episode that raises (policy, scene) is never a failed episode: its outcome has success None and
        its one-line ``error``; "raise" (default) raises :class:`EvaluationError` after the last episode,
        "report" returns the result with them (``success_rate`` then counts only the episodes that ran).
    label: what the error names (e.g. the benchmark cell).
    Returns successes, episodes, success_rate, wilson95, inference_ms_p50 (the model's wall-clock latency per
    call, median over every call of every episode), errors ([{"seed", "error"}]) and per-episode outcomes.
    """
    if on_error not in ("raise", "report"):
        raise ValueError(f"on_error must be 'raise' or 'report', got {on_error!r}")
    from envs.peg_in_hole import PegInHoleEnv  # the [sim] extra

    policy = load_policy(checkpoint)
    overrides = dict(env_overrides or {})
    if grip_force_range is not None:
        overrides["grip_force_range_n"] = tuple(grip_force_range)
    env_config = scene_config(scene, **overrides)
    check_setup(policy, env_config.cameras, SENSORS if env_config.tactile else ())
    # render only the streams the policy reads (a camera-only policy's episodes skip the tactile optics); physics and
    # the sensors' own noise draws do not depend on what is rendered
    env_config = dataclasses.replace(env_config, tactile=bool(policy.config.tactile_names),
                                     cameras=tuple(c for c in env_config.cameras if c in policy.config.camera_names))
    outcomes, inference_ms, clamps = [], [], {}
    with PegInHoleEnv(env_config) as env:
        bar = tqdm(range(episodes), desc="evaluate", disable=tty_only(progress), dynamic_ncols=True)
        for i in bar:
            r = _episode(policy, env, seed + i)
            inference_ms.extend(r.pop("inference_ms"))
            for k, v in r.pop("safety").items():
                clamps[k] = clamps.get(k, 0) + v
            outcomes.append(r)
            bar.set_postfix(success=f"{sum(o['success'] is True for o in outcomes)}/{len(outcomes)}")
    k = sum(o["success"] is True for o in outcomes)
    errors = [{"seed": o["seed"], "error": o["error"]} for o in outcomes if o["error"] is not None]
    ran = episodes - len(errors)
    result = {"successes": k, "episodes": episodes, "success_rate": k / ran if ran else 0.0,
              "wilson95": list(wilson_interval(k, ran)), "grip_force_range_n": list(env_config.grip_force_range_n),
              "inference_ms_p50": float(np.median(inference_ms)) if inference_ms else None,
              "safety_clamps": clamps, "errors": errors, "outcomes": outcomes}
    if errors and on_error == "raise":
        raise EvaluationError(result, label)
    return result


def deploy_on_robot(kind: str, checkpoint, setup_yaml: str | Path, max_steps: int | None = None) -> dict:
    """Run the policy on the robot described by ``setup_yaml`` (``hardware/configs/*.yaml``).

    Checked before any device is connected (the setup, the checkpoint against it, the setup's inference
    deadline against the policy's chunk); returns the loop's deadline statistics. A device that cannot be
    reached or fails is a :class:`~hardware.interfaces.HardwareError` naming the setup file.
    """
    setup_cfg = load_setup(setup_yaml)
    if setup_cfg.robot.type != kind:
        raise ValueError(f"--robot {kind}, but {setup_yaml} describes robot.type {setup_cfg.robot.type!r}")
    policy = load_policy(checkpoint)
    check_setup(policy, setup_cfg.cameras, setup_cfg.tactile)
    loop_config(setup_cfg, policy.config.chunk_size, policy.config.temporal_ensemble_coeff)
    with open_setup(setup_cfg) as setup:
        return deploy(setup, policy, max_steps=max_steps).summary()
