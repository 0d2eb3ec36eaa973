"""Peg-in-hole scene: physics stability, the jammed peg, bad input, the expert."""

import dataclasses
import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from envs.config import PegInHoleConfig, scene_config
from envs.expert import ExpertConfig, ScriptedExpert, wrap_half_turn
from envs.peg_in_hole import PegInHoleEnv


@pytest.fixture(scope="module")
def physics_env():
    env = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False))
    yield env
    env.close()


@pytest.mark.parametrize("value", [float("nan"), 1e12])
def test_a_diverging_simulation_stops_the_episode_in_one_line(value, tmp_path, monkeypatch, capfd):
    """NaN or a huge velocity (what a bad contact or timestep produces): the step raises with MuJoCo's own words,
    never returns NaN; MuJoCo neither prints nor writes MUJOCO_LOG.TXT, and its handler is restored."""
    import mujoco

    monkeypatch.chdir(tmp_path)  # MuJoCo's default handler logs to MUJOCO_LOG.TXT in the working directory
    env = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False))
    env.reset(seed=0)
    env.data.qvel[:] = value
    capfd.readouterr()
    with pytest.raises(RuntimeError, match=r"^simulation became unstable at step 1 \(MuJoCo: Nan, Inf or huge value "
                                           r"in QVEL at DOF 0\. The simulation is unstable\. Time = [0-9.]+\.\)$"):
        env.step(env.command)
    env.close()
    assert capfd.readouterr() == ("", "") and list(tmp_path.iterdir()) == []
    assert mujoco.get_mju_user_warning() is None


def test_a_scene_that_diverges_while_settling_stops_the_reset(tmp_path, monkeypatch, capfd):
    """A timestep far too long for the contacts: reset raises naming the episode, never starts it from MuJoCo's
    own reset pose."""
    monkeypatch.chdir(tmp_path)
    env = PegInHoleEnv(PegInHoleConfig(cameras=(), tactile=False))
    env.model.opt.timestep = 5.0
    with pytest.raises(RuntimeError, match=r"^simulation became unstable while episode 3 settled \(MuJoCo: Nan, Inf "
                                           r"or huge value in QACC"):
        env.reset(seed=3)
    env.close()
    assert capfd.readouterr().out == "" and list(tmp_path.iterdir()) == []


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


INF, NAN = float("inf"), float("nan")


@pytest.mark.parametrize("kwargs, fields", [
    # rates: non-finite, non-positive, implausible, not a number
    ({"control_hz": INF}, ["control_hz", "Hz"]),
    ({"control_hz": NAN}, ["control_hz", "Hz"]),
    ({"control_hz": -10.0}, ["control_hz", "Hz"]),
    ({"control_hz": 0.0}, ["control_hz", "Hz"]),
    ({"control_hz": 1000.0}, ["control_hz", "Hz"]),
    ({"control_hz": 0.5}, ["control_hz", "Hz"]),
    ({"control_hz": "10"}, ["control_hz", "number"]),
    # workspace: infinite, NaN, inverted, implausibly large, not numbers
    ({"workspace_high": (INF, 0.2, 0.4, 3.14)}, ["workspace_high", "finite"]),
    ({"workspace_low": (-0.16, -0.14, -INF, -1.5)}, ["workspace_low", "finite"]),
    ({"workspace_low": (-0.16, NAN, 0.012, -1.5)}, ["workspace_low", "finite"]),
    ({"workspace_low": (0.16, -0.14, 0.012, -1.5), "workspace_high": (-0.16, 0.14, 0.25, 1.5)},
     ["workspace_low", "workspace_high", "low < high"]),
    ({"workspace_low": (-100.0, -100.0, 0.012, -1.5), "workspace_high": (100.0, 100.0, 0.25, 1.5)},
     ["workspace", "table"]),
    ({"workspace_low": (-0.16, -0.14, -0.1, -1.5)}, ["workspace_low", "z"]),
    ({"workspace_high": (0.16, 0.14, 0.25, 10.0)}, ["workspace_high", "yaw"]),
    ({"workspace_high": ("a", 0.14, 0.25, 1.5)}, ["workspace_high", "numbers"]),
    # booleans given as strings or numbers
    ({"tactile": "no"}, ["tactile", "True or False"]),
    ({"tactile": "False"}, ["tactile", "True or False"]),
    ({"tactile_noise": 1}, ["tactile_noise", "True or False"]),
    ({"peg_in_hand": "yes"}, ["peg_in_hand", "True or False"]),
    ({"tactile": None}, ["tactile", "True or False"]),
    # ints given as booleans or fractions, names as strings
    ({"max_steps": True}, ["max_steps", "int"]),
    ({"ray_stride": 2.5}, ["ray_stride", "int"]),
    ({"camera_size": (96.5, 128)}, ["camera_size", "int"]),
    ({"cameras": "wrist"}, ["cameras", "tuple"]),
    # non-finite or non-numeric float fields
    ({"hole_diameter_mm": NAN}, ["hole_diameter_mm", "finite"]),
    ({"hole_diameter_mm": "30"}, ["hole_diameter_mm", "number"]),
    ({"hole_depth_mm": INF}, ["hole_depth_mm", "finite"]),
    ({"hole_chamfer_mm": NAN}, ["hole_chamfer_mm", "finite"]),
    ({"success_depth_mm": NAN}, ["success_depth_mm", "finite"]),
    ({"grasp_depth_mm": INF}, ["grasp_depth_mm", "finite"]),
    ({"grip_force_range_n": (NAN, 5.0)}, ["grip_force_range_n", "finite"]),
    ({"grip_force_range_n": ("3", "9")}, ["grip_force_range_n", "numbers"]),
    ({"peg_yaw_range_rad": (-INF, 0.0)}, ["peg_yaw_range_rad", "finite"]),
    ({"peg_xy_range_m": ((NAN, 0.0), (0.0, 0.0))}, ["peg_xy_range_m", "finite"]),
])
def test_config_refuses_wrong_types_and_non_finite_values_in_one_line(kwargs, fields):
    with pytest.raises(ValueError) as err:
        PegInHoleConfig(**kwargs)
    msg = str(err.value)
    assert "\n" not in msg.strip()
    for f in fields:
        assert f.lower() in msg.lower(), (f, msg)


# ranges under which an episode succeeded at reset before the check (the peg placed in or on the
# receptacle, or the held peg dragged into the hole by a workspace below the hand's start)
SUCCEED_AT_RESET = {
    "peg range = hole range": dict(peg_xy_range_m=((0.065, 0.075), (-0.005, 0.005))),
    "peg 10 mm off the hole's centre": dict(peg_xy_range_m=((0.06, 0.06), (0.0, 0.0)),
                                            hole_xy_range_m=((0.07, 0.07), (0.0, 0.0))),
    "overlapping ranges near the origin": dict(peg_xy_range_m=((-0.01, 0.01), (-0.01, 0.01)),
                                               hole_xy_range_m=((-0.005, 0.005), (-0.005, 0.005))),
}


@pytest.mark.parametrize("case", sorted(SUCCEED_AT_RESET))
def test_peg_and_hole_ranges_that_succeed_at_reset_are_refused(case):
    with pytest.raises(ValueError) as err:
        PegInHoleConfig(cameras=(), tactile=False, **SUCCEED_AT_RESET[case])
    msg = str(err.value)
    assert "peg_xy_range_m" in msg and "hole_xy_range_m" in msg and "\n" not in msg


@pytest.mark.parametrize("kwargs, fields", [
    # the hand starts at the home keyframe (0, 0, 0.15 m, yaw 0): a workspace below it drags the hand
    # (and a held peg) down during the reset's settling step, into the hole
    (dict(peg_in_hand=True, peg_xy_range_m=((0.07, 0.07), (0.0, 0.0)), hole_xy_range_m=((0.07, 0.07), (0.0, 0.0)),
          workspace_high=(0.16, 0.14, 0.03, 1.57)), ["workspace_high", "start"]),
    (dict(workspace_low=(0.02, -0.14, 0.012, -1.57)), ["workspace_low", "start"]),
    (dict(workspace_low=(-0.16, -0.14, 0.012, 0.1)), ["workspace_low", "start"]),
    # with the peg in the hand, peg_xy_range_m is where the hand starts: inside the workspace
    (dict(peg_in_hand=True, peg_xy_range_m=((-0.15, -0.05), (-0.02, 0.02)), workspace_low=(-0.1, -0.14, 0.012, -1.57)),
     ["peg_xy_range_m", "workspace_low"]),
])
def test_a_hand_start_outside_the_workspace_is_refused(kwargs, fields):
    with pytest.raises(ValueError) as err:
        PegInHoleConfig(cameras=(), tactile=False, **kwargs)
    msg = str(err.value)
    assert "\n" not in msg and all(f in msg for f in fields), msg


DIMENSIONS = ("PEG_RADIUS_M", "PEG_HALF_LENGTH_M", "TABLE_HALF_SIZE_M", "PHYSICS_HZ", "HOME_TCP",
              "WALL_THICKNESS_M", "BASE_THICKNESS_M")


def test_scene_dimensions_have_one_owner_that_python_and_the_model_agree_on(physics_env):
    """The MJCF owns the peg's size, the table's, the timestep and the home pose: envs.geometry reads them
    from its text (what the config checks before any model exists), the env from the compiled model (its
    public ``peg_radius_m``, ``peg_half_length_m``, ``home_tcp``); the two readings are equal. envs.geometry
    owns the receptacle's dimensions, and the built model has them. No other module holds its own copy."""
    from envs import config, expert, geometry, peg_in_hole, scene

    env, m = physics_env, physics_env.model
    peg = tuple(float(v) for v in m.geom("peg").size[:2])
    assert (geometry.PEG_RADIUS_M, geometry.PEG_HALF_LENGTH_M) == (env.peg_radius_m, env.peg_half_length_m) == peg
    hand = [m.joint(n).qposadr[0] for n in geometry.HAND_JOINTS]
    assert geometry.HOME_TCP == tuple(float(v) for v in m.key("home").qpos[hand])
    assert np.array_equal(env.home_tcp, geometry.HOME_TCP)
    # the qpos layout geometry reads the keyframe with is MuJoCo's, for the scene and for the gripper alone
    assert geometry.qpos_addresses(geometry.read_mjcf()) == {m.joint(i).name: int(m.jnt_qposadr[i]) for i in range(m.njnt)}
    assert geometry.PHYSICS_HZ == 1.0 / m.opt.timestep
    assert geometry.TABLE_HALF_SIZE_M == m.geom("table").size[:2].max()
    floor = m.geom("hole_floor")
    assert floor.size[0] == env.config.hole_diameter_mm / 2000 + geometry.WALL_THICKNESS_M
    assert floor.size[2] == geometry.BASE_THICKNESS_M / 2
    # one owner: every module that uses a dimension has envs.geometry's object, not a copy of its value
    for module in (config, expert, peg_in_hole, scene):
        for name in DIMENSIONS:
            assert getattr(module, name, getattr(geometry, name)) is getattr(geometry, name), (module.__name__, name)
    # a held peg starts above every rim the config allows (shallowest grasp, deepest hole)
    assert geometry.HOME_TCP[2] + 0.010 - 2 * geometry.PEG_HALF_LENGTH_M > geometry.rim_height_m(60.0)


def test_closest_allowed_ranges_start_clear_of_the_receptacle():
    """The nearest peg range the check allows (touching the receptacle's footprint) does not succeed."""
    from envs.geometry import PEG_RADIUS_M, WALL_THICKNESS_M

    hole_x, r_out = 0.07, 0.015 + WALL_THICKNESS_M
    peg_x = hole_x - r_out - PEG_RADIUS_M - 1e-4
    cfg = PegInHoleConfig(cameras=(), tactile=False, peg_xy_range_m=((peg_x, peg_x), (0.0, 0.0)),
                          hole_xy_range_m=((hole_x, hole_x), (0.0, 0.0)))
    with pytest.raises(ValueError, match="peg_xy_range_m"):
        dataclasses.replace(cfg, peg_xy_range_m=((peg_x + 2e-4, peg_x + 2e-4), (0.0, 0.0)))
    with PegInHoleEnv(cfg) as env:
        env.reset(seed=0)
        _, _, terminated, _, info = env.step(env.command)
        assert not terminated and not info["success"] and info["insertion_mm"] == 0.0


def test_config_repr_is_unchanged():
    """benchmarks.touch_il hashes the repr: valid configs must keep it."""
    assert repr(PegInHoleConfig()) == (
        "PegInHoleConfig(cameras=('third_view', 'wrist'), camera_size=(96, 128), tactile=True, tactile_size=(120, 160), "
        "tactile_optics='three_light', ray_stride=3, hole_diameter_mm=30.0, hole_depth_mm=40.0, hole_chamfer_mm=3.0, "
        "control_hz=10.0, max_steps=120, grip_force_range_n=(3.0, 9.0), peg_xy_range_m=((-0.07, -0.05), (-0.02, 0.02)), "
        "peg_yaw_range_rad=(-0.7853981633974483, 0.7853981633974483), hole_xy_range_m=((0.065, 0.075), (-0.005, 0.005)), "
        "workspace_low=(-0.16, -0.14, 0.012, -1.5707963267948966), workspace_high=(0.16, 0.14, 0.25, 1.5707963267948966), "
        "success_depth_mm=30.0, tactile_noise=True, peg_in_hand=False, in_hand_offset_mm=(0.0, 0.0), grasp_depth_mm=18.0, "
        "camera_layout='side')")
    tc = PegInHoleConfig.touch_critical()
    assert repr(tc) == (
        "PegInHoleConfig(cameras=('third_view', 'wrist'), camera_size=(96, 128), tactile=True, tactile_size=(120, 160), "
        "tactile_optics='three_light', ray_stride=3, hole_diameter_mm=30.0, hole_depth_mm=40.0, hole_chamfer_mm=2.0, "
        "control_hz=10.0, max_steps=60, grip_force_range_n=(4.0, 7.0), peg_xy_range_m=((-0.06, -0.04), (-0.02, 0.02)), "
        "peg_yaw_range_rad=(0.0, 0.0), hole_xy_range_m=((0.065, 0.075), (-0.005, 0.005)), "
        "workspace_low=(-0.16, -0.14, 0.012, -1.5707963267948966), workspace_high=(0.16, 0.14, 0.25, 1.5707963267948966), "
        "success_depth_mm=30.0, tactile_noise=True, peg_in_hand=True, in_hand_offset_mm=(5.0, 8.0), grasp_depth_mm=18.0, "
        "camera_layout='occluding')")
    assert dataclasses.replace(tc) == tc and scene_config("touch_critical") == tc


def test_configs_are_strict_pydantic_dataclasses_with_one_line_errors():
    """The project's config idiom (controltac_il.config): unknown fields refused; every error one line
    naming each field at fault."""
    from pydantic.dataclasses import is_pydantic_dataclass

    for cls in (PegInHoleConfig, ExpertConfig):
        assert is_pydantic_dataclass(cls)
        with pytest.raises(ValueError) as err:
            cls(colour="red")
        assert str(err.value).startswith("colour:") and "\n" not in str(err.value)
    with pytest.raises(ValueError) as err:
        ExpertConfig(free_noise_mm="1", grasp_offset_mm=(3.0, -3.0))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("free_noise_mm:") and "; grasp_offset_mm:" in msg, msg
    with pytest.raises(ValueError, match="^in_hand_offset_mm: needs peg_in_hand=True"):
        PegInHoleConfig(in_hand_offset_mm=(1.0, 2.0))


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
    for r in doc["step_timing"]:  # one 100 ms control period per step: the real-time factor is 100 ms over it
        assert r["steps"] > 0 and r["realtime_factor"] == pytest.approx(100.0 / r["ms_per_step"], rel=1e-9)
        assert r["steps_per_s"] == pytest.approx(1000.0 / r["ms_per_step"], rel=1e-9)
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

