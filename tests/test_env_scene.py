"""Peg-in-hole scene: physics stability, the jammed peg, bad input, the expert."""

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from envs.config import PegInHoleConfig
from envs.expert import ExpertConfig, ScriptedExpert, wrap_half_turn
from envs.peg_in_hole import PegInHoleEnv


@pytest.fixture(scope="module")
def physics_env():
    env = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False))
    yield env
    env.close()


def test_random_actions_stay_finite_without_warnings(physics_env):
    env = physics_env
    rng = np.random.default_rng(0)
    low = np.array([*env.config.workspace_low, 0.0]) - 0.05
    high = np.array([*env.config.workspace_high, 1.0]) + 0.05
    env.reset(seed=1)
    for _ in range(1000):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(low, high))
        assert np.isfinite(obs["qpos"]).all()
        assert all(np.isfinite(obs[f"force/{s}"]).all() for s in ("left", "right"))
        if terminated or truncated:
            env.reset(seed=int(rng.integers(1000)))
    assert np.isfinite(env.data.qpos).all() and np.isfinite(env.data.qvel).all()
    assert sum(w.number for w in env.data.warning) == 0


def test_expert_inserts_peg_and_reports_success(physics_env):
    env = physics_env
    expert = ScriptedExpert(env)
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        assert not info["success"] and info["insertion_mm"] == 0.0
        expert.reset(seed)
        for _ in range(env.config.max_steps):
            obs, reward, terminated, truncated, info = env.step(expert.act())
            if terminated or truncated:
                break
        assert terminated and info["success"] and reward == 1.0
        assert info["insertion_mm"] >= env.config.success_depth_mm
        # the peg really is in the hole: its bottom within the hole's radius of the hole's centre
        assert np.linalg.norm(env.peg_bottom()[:2] - env.hole_xy) < env.config.hole_diameter_mm / 2000
        # the held peg is squeezed with the episode's grip force
        assert obs["force/left"][2] == pytest.approx(info["grip_force_n"], rel=0.05)


def test_jammed_peg_keeps_penetration_bounded(physics_env):
    env = physics_env
    expert = ScriptedExpert(env)
    env.reset(seed=3)
    expert.reset(3)
    while expert.phase != "align":
        env.step(expert.act())
    z, yaw = env.tcp_pose()[2:]
    held = env.peg_bottom()[:2] - env.tcp_pose()[:2]
    over_rim = env.hole_xy + np.array([0.015, 0.0]) - held  # peg axis on the rim circle
    for _ in range(10):
        env.step([*over_rim, z, yaw, 1.0])
    rim = env.config.hole_depth_mm / 1000 + 0.008
    worst = 0.0
    for _ in range(30):  # drive far below the rim: the servo pushes with its 40 N limit
        obs, _, terminated, _, info = env.step([*over_rim, 0.0, yaw, 1.0])
        worst = max(worst, info["max_penetration_mm"])
        assert info["clipped"]  # z = 0 is below the workspace
        assert not terminated
    assert 0.0 < worst < 3.0
    assert env.peg_bottom()[2] > rim - 0.003  # the peg sits on the rim, it did not pass through it
    assert np.isfinite(env.data.qpos).all()


@pytest.mark.parametrize("action", [np.zeros(4), np.zeros(6), np.zeros((1, 5)), "abc", [0, 0, 0.1, 0, None]])
def test_bad_action_shape_is_an_error(physics_env, action):
    physics_env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        physics_env.step(action)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_action_is_an_error(physics_env, bad):
    physics_env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        physics_env.step([0.0, 0.0, 0.1, bad, 0.0])


def test_out_of_workspace_target_is_clipped_and_flagged(physics_env):
    env = physics_env
    env.reset(seed=0)
    _, _, _, _, info = env.step([0.0, 0.0, 0.15, 0.0, 0.0])
    assert not info["clipped"]
    for _ in range(5):
        _, _, _, _, info = env.step([1.0, 0.0, 0.15, 0.0, 2.0])
        assert info["clipped"]
    high_x = env.config.workspace_high[0]
    assert env.tcp_pose()[0] == pytest.approx(high_x, abs=2e-3)  # it went to the bound, not beyond
    clipped, flag = env.check_action([0.0, -9.0, 0.1, 9.0, -1.0])
    assert flag and clipped.tolist() == [0.0, env.config.workspace_low[1], 0.1, env.config.workspace_high[3], 0.0]


def test_reset_is_deterministic_and_randomises_the_scene(physics_env):
    env = physics_env
    _, a = env.reset(seed=5)
    peg_a, hole_a = env.peg_pose()[0], env.hole_xy.copy()
    _, b = env.reset(seed=5)
    assert np.array_equal(env.peg_pose()[0], peg_a) and np.array_equal(env.hole_xy, hole_a)
    assert a["grip_force_n"] == b["grip_force_n"]
    _, c = env.reset(seed=6)
    assert not np.array_equal(env.hole_xy, hole_a) and c["grip_force_n"] != a["grip_force_n"]
    lo, hi = env.config.grip_force_range_n
    assert lo <= c["grip_force_n"] <= hi


@pytest.mark.parametrize("kwargs, field", [
    ({"cameras": ("top",)}, "cameras"),
    ({"camera_size": (96,)}, "camera_size"),
    ({"tactile_size": (60, 60)}, "tactile_size"),
    ({"control_hz": 7.0}, "control_hz"),
    ({"hole_diameter_mm": 24.0}, "hole_diameter_mm"),
    ({"grip_force_range_n": (5.0, 2.0)}, "grip_force_range_n"),
    ({"tactile_optics": "phong"}, "tactile_optics"),
    ({"workspace_low": (0, 0, 0)}, "workspace_low"),
])
def test_config_rejects_bad_fields(kwargs, field):
    with pytest.raises(ValueError, match=field):
        PegInHoleConfig(**kwargs)


def test_expert_config_and_yaw_wrap():
    with pytest.raises(ValueError, match="grasp_depth_mm"):
        ExpertConfig(grasp_depth_mm=(2.0, 5.0))
    assert wrap_half_turn(math.pi * 0.75) == pytest.approx(-math.pi / 4)
    assert wrap_half_turn(-math.pi * 0.75) == pytest.approx(math.pi / 4)
    assert wrap_half_turn(0.3) == pytest.approx(0.3)


@pytest.mark.slow
def test_benchmark_quick_run_writes_results(tmp_path):
    import json

    from benchmarks import env as bench

    out = tmp_path / "env.json"
    bench.main(["--quick", "--seeds", "2", "--out", str(out)])
    doc = json.loads(out.read_text())
    assert doc["machine"]["cores"] >= 1
    assert [r["setting"] for r in doc["step_timing"]] == list(bench.SETTINGS)
    assert all(r["ms_per_step"] > 0 and r["steps"] > 0 for r in doc["step_timing"])
    assert doc["expert"][0]["episodes"] == 2 and doc["expert"][0]["successes"] == 2


def test_only_requested_streams_are_rendered():
    with PegInHoleEnv(PegInHoleConfig(cameras=("wrist",), camera_size=(48, 64), tactile=False)) as env:
        obs, _ = env.reset(seed=2)
        assert set(obs) == {"qpos", "images/wrist", "force/left", "force/right"}
        wrist = obs["images/wrist"]
        assert wrist.shape == (48, 64, 3) and wrist.dtype == np.uint8
        with pytest.raises(ValueError, match="sensor"):
            env.tactile_background("left")
        # the blue peg is in view once the hand hovers above it, and the image follows the scene
        x, y = env.peg_pose()[0][:2]
        for _ in range(8):
            obs, *_ = env.step([x - 0.03, y, 0.14, 0.0, 0.0])
        img = obs["images/wrist"].astype(int)
        blue = (img[..., 2] > img[..., 0] + 60).mean()
        assert blue > 0.01
        assert not np.array_equal(obs["images/wrist"], wrist)


@pytest.mark.parametrize("chamfer, shapes", [(0.0, ((96, 3), (192, 3))), (0.003, ((120, 3), (240, 3)))])
def test_receptacle_tube_mesh_faces_outward(chamfer, shapes):
    from envs.scene import tube_mesh

    r_in, r_out, z0, z1 = 0.015, 0.027, 0.008, 0.048
    vertices, faces = tube_mesh(r_in, r_out, z0, z1, 24, chamfer=chamfer)
    assert (vertices.shape, faces.shape) == shapes
    # the rim's inner edge is pushed out by the chamfer, the wall below it is not
    top = vertices[np.isclose(vertices[:, 2], z1)]
    assert np.linalg.norm(top[:, :2], axis=1).min() == pytest.approx(r_in + chamfer)
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    radial = np.linalg.norm(centre[:, :2], axis=1)
    # from the tube's material core (mid radius, mid height) towards each face
    core = np.column_stack([centre[:, :2] * ((r_in + r_out) / 2 / radial)[:, None], np.full(len(faces), (z0 + z1) / 2)])
    assert (np.einsum("ij,ij->i", normal, centre - core) > 0).all()


@pytest.mark.parametrize("chamfer_mm", [0.0, 3.0])
def test_lead_in_chamfer_guides_a_peg_beyond_the_clearance(chamfer_mm):
    """A peg lowered 4 mm off the hole's axis (radial clearance 2.5 mm) mostly catches on a sharp rim
    but slides down a 3 mm chamfer into the hole (6 tries: 2 scenes x 3 directions of the offset)."""
    inserted = 0
    with PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False, hole_chamfer_mm=chamfer_mm)) as env:
        expert = ScriptedExpert(env)
        for seed in (1, 2):
            for offset in ([0.0, 0.004], [0.004, 0.0], [0.0, -0.004]):
                env.reset(seed=seed)
                expert.reset(seed)
                while expert.phase != "align":
                    env.step(expert.act())
                z, yaw = env.tcp_pose()[2:]
                held = env.peg_bottom()[:2] - env.tcp_pose()[:2]
                target = env.hole_xy + np.array(offset) - held
                for _ in range(5):
                    env.step([*target, z, yaw, 1.0])
                for k in range(1, 15):  # push the peg's bottom down to 3 mm above the floor
                    env.step([*target, z + (0.011 + 0.045 - z) * k / 14, yaw, 1.0])
                inserted += env.insertion_mm() >= env.config.success_depth_mm
    if chamfer_mm:
        assert inserted >= 5
    else:
        assert inserted <= 2

