"""Tactile fingers: ray-cast penetration maps, pad forces, images through the sensor model."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from controltac_il.tactile import to_residual
from envs.config import PegInHoleConfig
from envs.geometry import PEG_RADIUS_M, WALL_THICKNESS_M
from envs.peg_in_hole import PEG_RAYS, PegInHoleEnv
from envs.tactile_rig import PadRays

SIZE = (60, 80)  # small tactile images keep the tests fast; the pad's physical size is unchanged


@pytest.fixture(scope="module")
def env():
    e = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=True, tactile_size=SIZE))
    yield e
    e.close()


@pytest.fixture(autouse=True)
def _default_grip(request):
    """A test that sets the shared env's grip force (``grasp``) leaves it at the scene's default for the next: no
    test depends on the order xdist runs them in."""
    yield
    if "env" in request.fixturenames:
        request.getfixturevalue("env").config.grip_force_range_n = PegInHoleConfig().grip_force_range_n


def grasp(env, grip_n, seed=0, lift=True):
    """Reset with a fixed grip force, grasp the peg straight (no offset) and optionally lift it."""
    env.config.grip_force_range_n = (grip_n, grip_n)
    obs, _ = env.reset(seed=seed)
    x, y = env.peg_pose()[0][:2]
    plan = [[x, y, 0.062, 0.0, 0.0]] * 6 + [[x, y, 0.062, 0.0, 1.0]] * 5
    plan += [[x, y, 0.10, 0.0, 1.0]] * 3 if lift else []
    for a in plan:
        obs, *_ = env.step(a)
    return obs


def test_no_contact_residual_is_grey_plus_noise(env):
    obs, _ = env.reset(seed=0)
    for s in ("left", "right"):
        assert not env.pad_in_contact(s)
        assert not env.penetration_mm(s).any()
        res = to_residual(obs[f"tactile/{s}"], env.tactile_background(s)).astype(np.float64)
        assert abs(res.mean() - 127.0) < 0.5
        assert 0.3 < res.std() < 3.0  # the sensor model's noise, nothing else
        assert np.abs(res - 127).max() <= 12
        np.testing.assert_array_equal(obs[f"force/{s}"], 0.0)


def test_noise_free_no_contact_image_is_the_background():
    e = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile_size=SIZE, tactile_noise=False))
    try:
        obs, _ = e.reset(seed=0)
        for s in ("left", "right"):
            background = e.tactile_background(s)
            assert background.shape == (*SIZE, 3) and background.dtype == np.uint8
            np.testing.assert_array_equal(obs[f"tactile/{s}"], background)
    finally:
        e.close()


def test_tactile_intensity_and_force_grow_with_grip_force(env):
    intensity, depth, fz = [], [], []
    for grip in (2.0, 5.0, 9.0):
        obs = grasp(env, grip)
        res = to_residual(obs["tactile/left"], env.tactile_background("left")).astype(np.float64)
        intensity.append(np.abs(res - 127).mean())
        depth.append(env.penetration_mm("left").max())
        fz.append(obs["force/left"][2])
        # a held peg: pressed with the grip force, carrying half its weight along the sensor's y
        assert obs["force/left"][2] == pytest.approx(grip, rel=0.03)
        assert obs["force/right"][2] == pytest.approx(grip, rel=0.03)
        assert obs["force/left"][1] == pytest.approx(-0.05 * 9.81 / 2, rel=0.15)
    assert intensity[0] < intensity[1] < intensity[2]
    assert depth[0] < depth[1] < depth[2]
    # the gel's compliance follows the sensor model's mechanics for a Ø25 mm cylinder (0.13 / 0.25 / 0.36 mm)
    assert depth == pytest.approx([0.134, 0.247, 0.365], rel=0.2)


def test_penetration_strip_matches_the_peg_geometry(env):
    grasp(env, 6.0, lift=False)
    for s in ("left", "right"):
        rays = env.pad_rays(s)
        pen = env.penetration_mm(s)
        rot = rays.rotation
        site = env.data.site_xpos[rays.site_id]
        axis = rot.T @ (env.peg_pose()[0] - site) * 1000.0  # peg centre in the sensor frame, mm
        pitch = env.tactile_sensor(s).spec.mm_per_px
        h, w = SIZE
        # the imprint is a vertical strip centred on the peg's axis, as deep as the peg's overlap
        cols = (np.arange(w) + 0.5 - w / 2) * pitch
        profile = pen.max(axis=0)
        centre = (profile * cols).sum() / profile.sum()
        assert centre == pytest.approx(axis[0], abs=pitch)
        overlap = PEG_RADIUS_M * 1000.0 + axis[2]  # axis[2] < 0: the axis lies outside the gel
        assert profile.max() == pytest.approx(overlap, abs=0.01)
        half_width = np.sqrt(2 * PEG_RADIUS_M * 1000.0 * overlap)
        touched = cols[profile > 0]
        assert touched.max() - touched.min() == pytest.approx(2 * half_width, abs=2 * pitch)
        # the peg spans the pad's full height, so every row is touched
        assert (pen.max(axis=1) > 0).all()


@pytest.mark.parametrize("stride", [2, 3])
def test_ray_stride_interpolation_matches_full_resolution(env, stride):
    grasp(env, 6.0)
    pad_mm = env.tactile_sensor("left").spec.pad_size_mm
    full = PadRays(env.model, env.data, "left_sensor", SIZE, pad_mm, stride=1)
    coarse = PadRays(env.model, env.data, "left_sensor", SIZE, pad_mm, stride=stride)
    a, b = full.penetration_mm(PEG_RAYS), coarse.penetration_mm(PEG_RAYS)
    assert a.max() > 0.1
    assert np.abs(a - b).max() < 0.01
    assert ((a > 0) != (b > 0)).sum() <= a.shape[0]  # the contact edge moves by at most a pixel per row


def test_unknown_sensor_is_an_error(env):
    with pytest.raises(ValueError, match="sensor"):
        env.penetration_mm("middle")
    with pytest.raises(ValueError, match="sensor"):
        env.tactile_background("middle")


def test_episodes_are_reproducible_from_the_seed(env):
    """Same seed, same actions: identical observations (physics, forces, tactile noise included)."""
    from envs.expert import ScriptedExpert

    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=11)
        expert = ScriptedExpert(env)
        expert.reset(11)
        frames = []
        for _ in range(26):  # through the grasp: contact frames included
            obs, *_ = env.step(expert.act())
            frames.append(obs)
        runs.append(frames)
    assert runs[0][-1]["force/left"][2] > 1.0
    for a, b in zip(*runs):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    # the noise differs from frame to frame (seeded per step, not frozen)
    assert not np.array_equal(runs[0][0]["tactile/left"], runs[0][1]["tactile/left"])


def test_gel_pressed_on_the_receptacle_shows_in_image_and_force(env):
    """Squeezing the receptacle (no peg): rays see the static walls, so image and force label agree."""
    env.config.grip_force_range_n = (6.0, 6.0)
    obs, _ = env.reset(seed=0)
    hx, hy = env.hole_xy
    for a in [[hx, hy, 0.10, 0.0, 0.0]] * 8 + [[hx, hy, 0.03, 0.0, 0.0]] * 6 + [[hx, hy, 0.03, 0.0, 1.0]] * 6:
        obs, *_ = env.step(a)
    for s in ("left", "right"):
        assert not env.pad_in_contact(s)  # the peg is elsewhere
        assert obs[f"force/{s}"][2] == pytest.approx(6.0, rel=0.05)
        pen = env.penetration_mm(s)
        assert 0.0 < pen.max() < 1.0
        # a flat wall face: the imprint is a vertical band over the gel's full height, as wide as the
        # face of the receptacle's outer 16-gon (2 (r + wall) tan(pi / 16))
        assert (pen.max(axis=1) > 0).all()
        pitch = env.tactile_sensor(s).spec.mm_per_px
        touched = np.flatnonzero(pen.max(axis=0) > 0)
        face_mm = 2 * (env.config.hole_diameter_mm / 2 + WALL_THICKNESS_M * 1000) * np.tan(np.pi / 16)
        assert (touched.max() - touched.min() + 1) * pitch == pytest.approx(face_mm, abs=2 * pitch)
        res = to_residual(obs[f"tactile/{s}"], env.tactile_background(s)).astype(np.float64)
        assert np.abs(res - 127).mean() > 1.0
