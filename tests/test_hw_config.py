"""Setup files: the shipped examples load; malformed ones (wrong types, implausible values, duplicated
keys, no workspace box) fail with one line naming the file and the field; devices are built from a file
(Dynamixel on a pty, GelSight on a video file)."""

import dataclasses
import glob
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from hardware.cameras import GelSightMini
from hardware.check import main as check_main
from hardware.config import ConfigError, build_frame_sources, build_gripper, load_setup, parse_setup
from hardware.dynamixel import DynamixelGripper
from hardware.fake_serial import FakeDynamixelServo
from hardware.interfaces import VirtualClock

EXAMPLES = sorted(glob.glob(str(Path(__file__).resolve().parents[1] / "hardware" / "configs" / "*.yaml")))
BOX = {"workspace_min": [0.2, -0.3, 0.0], "workspace_max": [0.7, 0.3, 0.5]}
BASE = {"robot": {"type": "ur", "ip": "10.0.0.2", "model": "ur5"}, "limits": BOX}


def test_examples_load():
    assert len(EXAMPLES) >= 3
    kinds = set()
    for path in EXAMPLES:
        cfg = load_setup(path)
        kinds.add((cfg.robot.type, cfg.gripper.type))
        assert cfg.control.rate_hz == 10 and cfg.limits.max_step_m > 0
    assert {("xarm", "xarm"), ("ur", "robotiq"), ("ur", "dynamixel")} <= kinds


def test_values_reach_the_dataclasses():
    cfg = parse_setup({**BASE, "limits": {"workspace_min": [0, -0.5, 0], "workspace_max": [0.5, 0.5, 1], "max_step_m": 0.01,
                                          "max_rotation_rad": 0.06},
                       "control": {"rate_hz": 15, "inference": "sync"},
                       "tactile": {"left": {"device": "/dev/video2"}}})
    assert cfg.limits.workspace_min == (0.0, -0.5, 0.0) and cfg.limits.max_step_m == 0.01
    assert cfg.control.period_s == pytest.approx(1 / 15) and cfg.control.inference == "sync"
    t = cfg.tactile["left"]
    assert (t.crop_fraction, t.fps, t.size, t.background_frames) == (0.15, 25.0, (240, 320), 30)
    assert cfg.robot.tool_rotvec == pytest.approx((np.pi, 0.0, 0.0)) and cfg.gripper.type == "none"


def test_settings_are_frozen():
    cfg = parse_setup(BASE)
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign"):
        cfg.robot.ip = "10.0.0.3"
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign"):
        cfg.limits.max_step_m = 0.05


def limits(**kw):
    return {"limits": {**BOX, **kw}}


@pytest.mark.parametrize("patch, message", [
    ({"robot": {"type": "kuka"}}, r"robot\.type: Input should be 'xarm', 'ur' or 'sim' \(got 'kuka'\)"),
    ({"robot": {"type": "xarm"}}, r"robot\.ip: required for robot type 'xarm'"),
    ({"robot": {"type": "ur", "model": "ur5", "ip": "192.168.1"}}, r"robot\.ip: expected an IP address such as 192\.168\.1\.221 \(got '192\.168\.1'\)"),
    ({"robot": {"type": "ur", "model": "ur5", "ip": "10.0.0.2", "gain": 5000}}, r"robot\.gain: Input should be less than or equal to 2000 \(got 5000\)"),
    ({"robot": {"type": "ur", "model": "ur5", "ip": "10.0.0.2", "iP": "y"}}, r"robot\.iP: Unexpected keyword argument \(got 'y'\)$"),
    ({"robot": {"type": "xarm", "ip": "10.0.0.2", "tool_rpy": [3.1, 0, 0]}}, r"robot\.tool_rpy: expected \[roll, pitch\] \(2 values\)"),
    ({"robot": {"type": "xarm", "ip": "10.0.0.2", "tool_rpy": [3.2, 0]}}, r"robot\.tool_rpy: each angle must be within \[-pi, pi\]"),
    ({"robot": {"type": "xarm", "ip": "10.0.0.2", "tool_rpy": [180, 0]}}, r"robot\.tool_rpy: each angle must be within \[-pi, pi\] rad \(degrees\?\) \(got \[180\.0, 0\.0\]\)"),
    ({"robot": {"type": "ur", "model": "ur5", "ip": "10.0.0.2", "tool_rotvec": [0, 0, 4]}}, r"robot\.tool_rotvec: a rotation vector's length is its angle, at most pi rad"),
    ({"robot": {"type": "xarm", "ip": "10.0.0.2", "stop_on_warning": "yes"}}, r"robot\.stop_on_warning: Input should be a valid boolean"),
    ({"gripper": {"type": "dynamixel"}}, r"gripper\.port: required for a dynamixel gripper"),
    ({"gripper": {"type": "dynamixel", "port": "/dev/x"}}, r"gripper\.open_position: open_position and closed_position"),
    ({"gripper": {"type": "xarm"}}, r"gripper\.type: an xarm gripper needs robot\.type xarm"),
    ({"gripper": {"type": "robotiq", "port": "/dev/ttyUSB0", "force": "strong"}}, r"gripper\.force: Input should be a valid integer \(got 'strong'\)"),
    ({"gripper": {"type": "robotiq", "port": "/dev/ttyUSB0", "force": 300}}, r"gripper\.force: Input should be less than or equal to 255"),
    ({"gripper": {"type": "robotiq", "port": "/dev/ttyUSB0", "speed": 300}}, r"gripper\.speed: a Robotiq speed is 0-255 \(got 300\)"),
    (limits(max_step_m=-0.1), r"limits\.max_step_m: Input should be greater than 0 \(got -0\.1\)"),
    (limits(max_step_m=0.5), r"limits\.max_step_m: Input should be less than or equal to 0\.1 \(got 0\.5\)"),
    (limits(max_rotation_rad=1.0), r"limits\.max_rotation_rad: Input should be less than or equal to 0\.5"),
    (limits(max_step_m=float("inf")), r"limits\.max_step_m: Input should be a finite number \(got inf\)"),
    (limits(workspace_min=[0, 0]), r"limits\.workspace_min: expected \[x, y, z\] \(3 values\) \(got \[0, 0\]\)"),
    (limits(workspace_min=[0, 0, "a"]), r"limits\.workspace_min\[2\]: Input should be a valid number \(got 'a'\)"),
    (limits(workspace_min=[0, 0, float("nan")]), r"limits\.workspace_min\[2\]: Input should be a finite number"),
    (limits(workspace_min=[0.8, 0, 0]), r"limits\.workspace_min: must be below workspace_max on every axis"),
    (limits(gripper_min=0.6, gripper_max=0.4), r"limits\.gripper_min: must be below gripper_max"),
    (limits(yaw_min=-4), r"limits\.yaw_min: Input should be greater than or equal to -3\.14"),
    ({"limits": {"workspace_max": [1, 1, 1]}}, r"limits\.workspace_min: required: the box \(x, y, z in m, base frame\)"),
    ({"limits": None}, r"limits: the section is required: state workspace_min and workspace_max"),
    ({"control": {"chunk_size": 20}}, r"control\.chunk_size: the chunk size is the policy's: deployment takes it from "
                                      r"the checkpoint .*; remove it from the setup file \(got 20\)$"),
    ({"control": {"ensemble_k": 0.01}}, r"control\.ensemble_k: the temporal-ensembling decay is the policy's"),
    ({"control": {"inference": "threads"}}, r"control\.inference: Input should be 'async' or 'sync' \(got 'threads'\)"),
    ({"control": {"query_every": 2.5}}, r"control\.query_every: Input should be a valid integer \(got 2\.5\)"),
    ({"control": {"rate_hz": -10}}, r"control\.rate_hz: Input should be greater than 0 \(got -10\)"),
    ({"control": {"rate_hz": "10"}}, r"control\.rate_hz: Input should be a valid number \(got '10'\)"),
    ({"control": {"threads": 2}}, r"control\.threads: Unexpected keyword argument \(got 2\)$"),
    ({"cameras": {"wrist": {"size": [240, 320]}}}, r"cameras\.wrist\.device: Field required$"),
    ({"cameras": {"wrist": {"device": 3, "crop_fraction": 0.7}}}, r"cameras\.wrist\.crop_fraction: Input should be less than 0\.5 \(got 0\.7\)"),
    ({"cameras": {"wrist": {"device": 3, "fps": -30}}}, r"cameras\.wrist\.fps: Input should be greater than 0 \(got -30\)"),
    ({"cameras": {"wrist": {"device": 3, "size": [0, 320]}}}, r"cameras\.wrist\.size\[0\]: Input should be greater than or equal to 1"),
    ({"tactile": ["left"]}, r"tactile: Input should be a valid dictionary"),
    ({"tactile": {"left": {"device": 2.5}}}, r"tactile\.left\.device: expected a string \(path or name\) or an integer index \(got 2\.5\)"),
    ({"tactile": {"left": {"background_frames": 0}}}, r"tactile\.left\.background_frames: Input should be greater than or equal to 1"),
])
def test_errors_name_the_field(patch, message):
    with pytest.raises(ConfigError, match=r"^my\.yaml: " + message) as info:
        parse_setup({**BASE, **patch}, "my.yaml")
    assert "\n" not in str(info.value)  # one line


def test_every_error_on_one_line():
    with pytest.raises(ConfigError) as info:
        parse_setup({"robot": {"type": "ur", "model": "ur5", "ip": "h"}, "limits": {**BOX, "max_step_m": 1.0}}, "my.yaml")
    assert str(info.value) == ("my.yaml: robot.ip: expected an IP address such as 192.168.1.221 (got 'h'); "
                               "limits.max_step_m: Input should be less than or equal to 0.1 (got 1.0)")


def test_missing_sections_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="^setup: robot: Field required; limits: the section is required"):
        parse_setup({})
    with pytest.raises(ConfigError, match="^my.yaml: limits: the section is required: state workspace_min and "
                                          r"workspace_max \(x, y, z in m, base frame\); nothing has a default box$"):
        parse_setup({"robot": {"type": "sim"}}, "my.yaml")
    with pytest.raises(ConfigError, match="^my.yaml: expected a mapping of sections"):
        parse_setup(["robot"], "my.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: [unclosed\n")
    with pytest.raises(ConfigError, match="bad.yaml: not valid YAML") as info:
        load_setup(bad)
    assert "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="cannot read the setup file"):
        load_setup(tmp_path / "absent.yaml")
    weights = tmp_path / "model.safetensors"  # a binary file given by mistake
    weights.write_bytes(bytes([0x80, 0xFF, 0x00, 0x9C]) * 8)
    with pytest.raises(ConfigError, match="model.safetensors: cannot read the setup file"):
        load_setup(weights)


@pytest.mark.parametrize("text, message", [
    ("robot: {type: ur, ip: 10.0.0.2}\nrobot: {type: xarm, ip: 10.0.0.3}\n", r"robot: duplicated key \(lines 1 and 2\)"),
    ("robot:\n  type: ur\n  ip: 10.0.0.2\n  ip: 10.0.0.3\n", r"robot\.ip: duplicated key \(lines 3 and 4\)"),
    ("cameras:\n  wrist: {device: 0}\n  wrist: {device: 1}\n", r"cameras\.wrist: duplicated key \(lines 2 and 3\)"),
    ("limits:\n  workspace_min: [0, 0, 0]\n  max_step_m: 0.01\n  max_step_m: 0.05\n", r"limits\.max_step_m: duplicated key"),
])
def test_duplicated_keys_are_refused(tmp_path, text, message):
    path = tmp_path / "dup.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"dup\.yaml: " + message):
        load_setup(path)


def test_check_cli(tmp_path, capsys):
    assert check_main([EXAMPLES[0]]) == 0
    assert "valid setup" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"robot": {"type": "ur", "model": "ur5"}, "limits": BOX}))
    assert check_main([str(bad)]) == 2
    assert "robot.ip: required" in capsys.readouterr().err
    for seconds in ("nan", "-1", "inf"):
        with pytest.raises(SystemExit) as exc:
            check_main([EXAMPLES[0], "--connect", "--seconds", seconds])
        assert exc.value.code == 2 and "--seconds: expected a finite duration >= 0 s" in capsys.readouterr().err


@pytest.mark.usefixtures("dynamixel_latency")
def test_devices_built_from_a_file(tmp_path):
    video = str(tmp_path / "gel.avi")
    w = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*"FFV1"), 25, (160, 120))
    for i in range(6):
        w.write(np.full((120, 160, 3), 90 + i, np.uint8))
    w.release()
    with FakeDynamixelServo(dxl_id=4) as dev:
        setup = tmp_path / "setup.yaml"
        setup.write_text(textwrap.dedent(f"""
            robot: {{type: ur, model: ur5, ip: 10.0.0.2}}
            limits: {{workspace_min: [0.2, -0.3, 0.0], workspace_max: [0.7, 0.3, 0.5]}}
            gripper: {{type: dynamixel, port: {dev.port}, dxl_id: 4, open_position: 100, closed_position: 900}}
            tactile: {{left: {{device: {video}, background_frames: 2, size: [60, 80]}}}}
        """))
        cfg = load_setup(setup)
        clock = VirtualClock()
        clock.attach()  # the file plays in virtual time that moves only while this thread waits
        gripper = build_gripper(cfg, arm=None, clock=clock)
        assert isinstance(gripper, DynamixelGripper) and gripper.clock is clock
        with gripper:
            gripper.command(0.5)
            assert dev._get_i32(116) == 500
        _, tactile = build_frame_sources(cfg, clock)
        with tactile["left"] as gs:
            assert isinstance(gs, GelSightMini) and gs.background.shape == (60, 80, 3) and gs.clock is clock
            assert gs.latest().timestamp == pytest.approx(0.04)  # the background took frames 1 and 2 (25 fps)
        clock.detach()


def test_build_arm_from_the_file_settings():
    from hardware.config import build_arm
    from hardware.ur import URArm
    from hardware.xarm import XArm

    arm = build_arm(parse_setup({"robot": {"type": "xarm", "ip": "1.2.3.4", "stream_hz": 150}, "control": {"rate_hz": 20},
                                 "limits": {"workspace_min": [0.2, -0.3, 0.0], "workspace_max": [0.6, 0.3, 0.5],
                                            "max_step_m": 0.01, "max_rotation_rad": 0.05}}))
    assert isinstance(arm, XArm) and (arm.ip, arm.period_s, arm.stream_hz) == ("1.2.3.4", 0.05, 150)
    ur = build_arm(parse_setup({"robot": {"type": "ur", "model": "ur5", "ip": "fe80::1", "lookahead_time": 0.05, "gain": 600},
                                "limits": BOX}))
    assert isinstance(ur, URArm) and (ur.ip, ur.period_s, ur.lookahead_time, ur.gain) == ("fe80::1", 0.1, 0.05, 600)
    clock = VirtualClock()
    assert build_arm(parse_setup(BASE), clock).clock is clock
    with pytest.raises(ConfigError, match="'sim' is the MuJoCo scene"):
        build_arm(parse_setup({"robot": {"type": "sim"}, "limits": BOX}))
