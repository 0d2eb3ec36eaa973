"""Peg-in-hole scene as a gymnasium.Env: env checker, spaces from the model, keyframe, gripper MJCF, peg probe."""

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from envs.config import PegInHoleConfig, scene_config
from envs.peg_in_hole import PegInHoleEnv

import mujoco  # noqa: E402  (after envs.peg_in_hole: it selects the headless GL backend)

SMALL = dict(camera_size=(24, 32), tactile_size=(24, 32))


# the checker's advice that does not apply: the action is an absolute pose target (the robots'
# action space, not a normalised one) and TCP pose and pad forces have no finite bounds
@pytest.mark.filterwarnings("ignore:.*(symmetric and normalized|observation space m..imum value is):UserWarning")
@pytest.mark.parametrize("scene", ["default", "touch_critical"])
def test_gymnasium_env_checker_passes(scene):
    env = gym.make("envs.peg_in_hole:PegInHole-v0", config=scene_config(scene, **SMALL), render_mode="rgb_array")
    try:
        check_env(env.unwrapped)  # spaces, seeding (super().reset), determinism, render modes
        assert isinstance(env.unwrapped, gym.Env)
        env.reset(seed=0)
        assert env.render().shape == (24, 32, 3)
    finally:
        env.close()


def test_spaces_are_the_observation_keys_and_the_model_ctrlrange():
    cfg = PegInHoleConfig(cameras=("wrist",), workspace_low=(-0.1, -0.12, 0.02, -1.0), **SMALL)
    with PegInHoleEnv(cfg) as env:
        obs, _ = env.reset(seed=0)
        assert set(obs) == set(env.observation_space.spaces) and obs in env.observation_space
        assert set(obs) == {"qpos", "images/wrist", "tactile/left", "tactile/right", "force/left", "force/right"}
        for _ in range(3):
            obs, *_ = env.step(env.action_space.sample())
            assert obs in env.observation_space
        m = env.model
        pose = [m.actuator(n).id for n in ("hand_x", "hand_y", "hand_z", "hand_yaw")]
        assert m.actuator_ctrllimited.all()
        np.testing.assert_array_equal(m.actuator_ctrlrange[pose, 0], cfg.workspace_low)
        np.testing.assert_array_equal(env.action_space.low, [*cfg.workspace_low, 0.0])
        np.testing.assert_array_equal(env.action_space.high, [*cfg.workspace_high, 1.0])
        assert env.render() is None  # no render mode
    with PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False)) as env:
        assert set(env.observation_space.spaces) == {"qpos", "force/left", "force/right"}


def test_reset_draws_from_np_random_and_starts_from_the_home_keyframe():
    with PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False)) as env:
        env.reset(seed=3)
        cfg, rng = env.config, np.random.default_rng(3)  # np_random is the generator the seed makes
        draws = [rng.uniform(*r) for r in (*cfg.peg_xy_range_m, cfg.peg_yaw_range_rad, *cfg.hole_xy_range_m,
                                           cfg.grip_force_range_n)]
        assert env.hole_xy.tolist() == draws[3:5] and env.grip_force_n == draws[5]
        assert env.np_random.bit_generator.state == rng.bit_generator.state
        key = env.model.key("home")
        hand = [env.model.joint(n).qposadr[0] for n in ("hand_x", "hand_y", "hand_z", "hand_yaw")]
        np.testing.assert_allclose(env.tcp_pose(), key.qpos[hand], atol=2e-3)  # settled one step at home
        np.testing.assert_array_equal(env.command, [*key.qpos[hand], 0.0])
        with pytest.raises(ValueError, match="options"):
            env.reset(options={"hole_xy": (0, 0)})


def test_gripper_mjcf_compiles_on_its_own():
    from envs.geometry import GRIPPER_XML, qpos_addresses, read_mjcf

    m = mujoco.MjModel.from_xml_path(str(GRIPPER_XML))
    assert m.nu == 6 and m.nq == 6 and m.actuator_ctrllimited.all()
    assert {m.site(i).name for i in range(m.nsite)} == {"tcp", "left_sensor", "right_sensor"}
    assert qpos_addresses(read_mjcf(GRIPPER_XML)) == {m.joint(i).name: int(m.jnt_qposadr[i]) for i in range(m.njnt)}


def test_set_peg_offset_in_hand_moves_only_the_peg_along_the_gel():
    with PegInHoleEnv(scene_config("touch_critical", cameras=(), tactile=False)) as env:
        env.reset(seed=0)
        assert env.peg_offset_in_hand() == pytest.approx(env.in_hand_offset_m, abs=5e-4)
        drawn, tcp = env.in_hand_offset_m, env.tcp_pose()
        height = env.data.qpos[env.model.joint("peg").qposadr[0] + 2]
        env.set_peg_offset_in_hand(-0.006)
        assert env.peg_offset_in_hand() == pytest.approx(-0.006, abs=1e-12)
        assert env.peg_pose()[0][2] == height and np.array_equal(env.tcp_pose(), tcp)
        assert not env.data.qvel.any() and env.in_hand_offset_m == drawn
        # yawed hand: the offset is along the hand's x axis, not the world's
        env.data.qpos[env.model.joint("hand_yaw").qposadr[0]] = math.pi / 6
        env.set_peg_offset_in_hand(0.004)
        assert env.peg_offset_in_hand() == pytest.approx(0.004, abs=1e-12)


def test_what_is_rendered_never_changes_the_physics_or_the_scenes_draws():
    """Evaluation renders only a policy's streams: an episode must be the same step by step without the others."""
    def run(**streams):
        with PegInHoleEnv(scene_config("touch_critical", camera_size=(32, 40), tactile_size=(24, 32), **streams)) as env:
            env.reset(seed=5)
            rng, qpos = np.random.default_rng(0), []
            for _ in range(15):
                a = np.clip(env.command + rng.normal(0, 0.002, 5), env.action_space.low, env.action_space.high)
                qpos.append(env.step(a)[0]["qpos"].copy())
            return np.array(qpos), env.np_random.bit_generator.state

    (full, drawn), (bare, bare_drawn) = run(), run(cameras=(), tactile=False)
    np.testing.assert_array_equal(full, bare)
    assert drawn == bare_drawn
