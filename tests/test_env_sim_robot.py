"""The MuJoCo scene behind the hardware interfaces, driven by the shared control loop."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from dataclasses import replace

import numpy as np
import pytest

from envs.config import PegInHoleConfig
from envs.expert import ScriptedExpert
from envs.peg_in_hole import PegInHoleEnv
from envs.sim_robot import SimRobot
from hardware.control_loop import ControlLoop
from hardware.interfaces import ArmFault, SensorError


class ExpertPolicy:
    """The scripted expert as a policy (observation -> chunk): one-step chunks."""

    def __init__(self, env, seed):
        self.expert = ScriptedExpert(env)
        self.expert.reset(seed)
        self.observations = []

    def __call__(self, observation):
        self.observations.append(observation)
        return self.expert.act()[None, :]


@pytest.fixture(scope="module")
def env():
    e = PegInHoleEnv(PegInHoleConfig(cameras=("wrist",), camera_size=(48, 64), tactile_size=(60, 80)))
    yield e
    e.close()


def test_control_loop_drives_the_scene_to_success(env):
    with SimRobot(seed=4, env=env) as robot:  # a setup like hardware.config.open_setup's
        policy = ExpertPolicy(env, seed=4)  # the expert plans from the freshly reset scene
        loop = ControlLoop(robot.arm, policy, gripper=robot.gripper, cameras=robot.cameras, tactile=robot.tactile,
                           limits=robot.limits, clock=robot.clock, config=replace(robot.control, chunk_size=1))
        stats = loop.run(max_steps=env.config.max_steps, on_step=lambda step, obs, target: robot.success)
        assert robot.success and robot.steps < env.config.max_steps
        assert robot.last_info["insertion_mm"] >= env.config.success_depth_mm
    assert "on_step ended the run" in stats.stop_reason
    assert robot.control.inference == "sync" and robot.control.rate_hz == env.config.control_hz
    obs = policy.observations[-1]
    assert obs["qpos"].shape == (5,) and obs["qpos"].dtype == np.float32
    assert obs["images/wrist"].shape == (48, 64, 3)
    assert obs["tactile/left"].shape == (60, 80, 3)
    np.testing.assert_array_equal(obs["tactile_background/left"], env.tactile_background("left"))
    # the loop saw the real scene: the last observation holds the peg (gripper closed on it)
    assert obs["qpos"][4] > 0.5


def test_clock_steps_physics_and_devices_follow_commands(env):
    with SimRobot(seed=1, env=env) as robot:
        start = robot.arm.state().pose
        target = start + np.array([0.02, -0.01, -0.02, 0.1])
        robot.arm.servo(target)
        robot.gripper.command(1.0)
        robot.clock.sleep_until(0.3)
        assert robot.steps == 3 and robot.clock.now() == pytest.approx(0.3)
        state = robot.arm.state()
        assert state.timestamp == pytest.approx(0.3)
        np.testing.assert_allclose(state.pose, target, atol=1e-3)
        assert robot.gripper.state().position > 0.9  # nothing between the fingers: fully closed
        frame = robot.tactile["right"].latest()
        assert frame.index == 3 and frame.timestamp == pytest.approx(0.3)
        robot.clock.sleep_until(0.3)  # already there: no physics
        assert robot.steps == 3
        robot.arm.stop()
        robot.clock.sleep_until(0.5)
        np.testing.assert_allclose(robot.arm.state().pose, state.pose, atol=1e-3)  # stop holds the pose
        with pytest.raises(ArmFault):
            robot.arm.servo([0.0, 0.0, np.nan, 0.0])
        assert robot.limits.workspace_min == env.config.workspace_low[:3]
    with pytest.raises(SensorError):
        robot.cameras["wrist"].latest()
