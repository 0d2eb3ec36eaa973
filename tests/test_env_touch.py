"""The touch-critical peg-in-hole variant: only touch tells where the peg sits in the hand."""

import numpy as np
import pytest

from envs.config import PegInHoleConfig, scene_config
from envs.expert import ScriptedExpert
from envs.peg_in_hole import PegInHoleEnv


def _run_expert(env, seed: int) -> dict:
    expert = ScriptedExpert(env)
    env.reset(seed=seed)
    expert.reset(seed + 7919)
    for _ in range(env.config.max_steps):
        _, _, terminated, truncated, info = env.step(expert.act())
        if terminated or truncated:
            break
    return info


def test_touch_critical_is_a_named_preset_and_the_default_scene_is_unchanged():
    cfg = PegInHoleConfig.touch_critical()
    assert cfg.peg_in_hand and cfg.camera_layout == "occluding" and cfg.in_hand_offset_mm == (5.0, 8.0)
    # the offset exceeds the radial clearance plus the chamfer: inserting at the TCP cannot work
    assert cfg.in_hand_offset_mm[0] > (cfg.hole_diameter_mm - 25.0) / 2 + cfg.hole_chamfer_mm
    default = PegInHoleConfig()
    assert not default.peg_in_hand and default.camera_layout == "side" and default.hole_chamfer_mm == 3.0
    assert scene_config("touch_critical") == cfg and scene_config() == default
    assert PegInHoleConfig.touch_critical(grip_force_range_n=(1.5, 3.0)).grip_force_range_n == (1.5, 3.0)


@pytest.mark.parametrize("bad, match", [
    (dict(in_hand_offset_mm=(3.0, 2.0)), "in_hand_offset_mm"),
    (dict(in_hand_offset_mm=(0.0, 12.0)), "in_hand_offset_mm"),
    (dict(camera_layout="top"), "camera_layout"),
    (dict(grasp_depth_mm=50.0), "grasp_depth_mm"),
])
def test_bad_variant_settings_name_the_field(bad, match):
    with pytest.raises(ValueError, match=match):
        PegInHoleConfig.touch_critical(**bad)


def test_an_offset_without_the_variant_and_an_unknown_scene_are_refused_by_name():
    with pytest.raises(ValueError, match="peg_in_hand"):
        PegInHoleConfig(in_hand_offset_mm=(5.0, 8.0))
    with pytest.raises(ValueError, match="scene"):
        scene_config("peg_on_moon")


def test_episode_starts_with_the_peg_held_at_the_drawn_offset():
    cfg = PegInHoleConfig.touch_critical(cameras=(), tactile=False)
    offsets = []
    with PegInHoleEnv(cfg) as env:
        for seed in range(8):
            _, info = env.reset(seed=seed)
            held = env.peg_pose()[0][0] - env.tcp_pose()[0]
            assert abs(held - env.in_hand_offset_m) < 2e-4  # settled within 0.2 mm of the draw
            assert 5.0 <= abs(info["in_hand_offset_mm"]) <= 8.0
            assert env.pad_in_contact("left") and env.pad_in_contact("right")
            assert env.command[4] == 1.0  # the gripper is commanded closed from the start
            for _ in range(5):  # held, not dropped, while the hand waits
                env.step(env.command)
            assert abs(env.peg_bottom()[2] - (env.tcp_pose()[2] + cfg.grasp_depth_mm / 1000 - 0.08)) < 1e-3
            offsets.append(info["in_hand_offset_mm"])
    assert min(offsets) < 0 < max(offsets)  # both signs occur


def test_expert_compensates_the_offset_and_blind_insertion_fails():
    cfg = PegInHoleConfig.touch_critical(cameras=(), tactile=False)
    with PegInHoleEnv(cfg) as env:
        assert all(_run_expert(env, seed)["success"] for seed in range(6))
        for seed in range(6):  # the same motion without the offset correction lands on the rim
            env.reset(seed=seed)
            start, hole = env.command, env.hole_xy.copy()
            for k in range(1, 40):
                a = start.copy()
                a[:2] = start[:2] + (hole - start[:2]) * min(1.0, k / 14)
                a[2] = start[2] - 0.004 * max(0, k - 16)
                _, _, _, _, info = env.step(a)
            assert not info["success"] and info["insertion_mm"] < 5.0


@pytest.mark.slow
def test_expert_success_on_50_seeded_episodes_in_every_grip_band():
    for band in ((4.0, 7.0), (1.5, 3.0), (8.0, 10.0)):
        cfg = PegInHoleConfig.touch_critical(cameras=(), tactile=False, grip_force_range_n=band)
        with PegInHoleEnv(cfg) as env:
            wins = sum(_run_expert(env, seed)["success"] for seed in range(50))
        assert wins >= 48, (band, wins)


def test_the_cameras_still_show_the_hole():
    cfg = PegInHoleConfig.touch_critical(tactile=False)
    images = []
    with PegInHoleEnv(cfg) as env:
        for seed in range(6):
            obs, _ = env.reset(seed=seed)
            images.append(obs["images/third_view"].astype(np.int16))
    # the hole moves between episodes by up to 10 mm, i.e. several pixels: the images differ
    assert max(np.abs(images[0] - im).max() for im in images[1:]) > 40


def test_tactile_contact_grows_with_grip_force():
    def contact(grip: float) -> tuple[float, float]:
        cfg = PegInHoleConfig.touch_critical(cameras=(), tactile_noise=False, grip_force_range_n=(grip, grip))
        with PegInHoleEnv(cfg) as env:
            obs, _ = env.reset(seed=1)
            mag = np.abs(obs["tactile/left"].astype(np.float32) - env.tactile_background("left")).sum(axis=2)
            return float((mag > 6).mean()), float(mag.mean())

    (area_lo, mean_lo), (area_mid, mean_mid), (area_hi, mean_hi) = contact(1.5), contact(5.5), contact(10.0)
    assert area_lo < area_mid < area_hi
    assert mean_lo < mean_mid < mean_hi
    assert area_hi > 1.3 * area_lo and mean_hi > 1.5 * mean_lo
