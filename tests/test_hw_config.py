"""Setup files: the shipped examples load; malformed ones fail with the file and field named;
devices are built from a file (Dynamixel on a pty, GelSight on a video file)."""

import glob
import textwrap

import cv2
import numpy as np
import pytest
import yaml

from hardware.cameras import GelSightMini
from hardware.check import main as check_main
from hardware.config import ConfigError, build_frame_sources, build_gripper, load_setup, parse_setup
from hardware.dynamixel import DynamixelGripper
from hardware.fake_serial import FakeDynamixelServo

EXAMPLES = sorted(glob.glob("hardware/configs/*.yaml"))
BASE = {"robot": {"type": "ur", "ip": "10.0.0.2"}}


def test_examples_load():
    assert len(EXAMPLES) >= 3
    kinds = set()
    for path in EXAMPLES:
        cfg = load_setup(path)
        kinds.add((cfg.robot.type, cfg.gripper.type))
        assert cfg.control.rate_hz == 10 and cfg.limits.max_step_m > 0
    assert {("xarm", "xarm"), ("ur", "robotiq"), ("ur", "dynamixel")} <= kinds


def test_values_reach_the_dataclasses():
    cfg = parse_setup({**BASE, "limits": {"workspace_min": [0, -1, 0], "workspace_max": [1, 1, 1], "max_step_m": 0.01},
                       "control": {"rate_hz": 15, "inference": "sync"},
                       "tactile": {"left": {"device": "/dev/video2"}}})
    assert cfg.limits.workspace_min == (0.0, -1.0, 0.0) and cfg.limits.max_step_m == 0.01
    assert cfg.control.period_s == pytest.approx(1 / 15) and cfg.control.inference == "sync"
    t = cfg.tactile["left"]
    assert (t.crop_fraction, t.fps, t.size, t.background_frames) == (0.15, 25.0, [240, 320], 30)


@pytest.mark.parametrize("patch, message", [
    ({"robot": {"type": "kuka"}}, r"robot\.type: expected 'xarm', 'ur' or 'sim'"),
    ({"robot": {"type": "xarm"}}, r"robot\.ip: required for robot type 'xarm'"),
    ({"robot": {"type": "ur", "ip": "x", "gain": 5000}}, r"robot\.gain: expected 100 to 2000"),
    ({"robot": {"type": "ur", "ip": "x", "iP": "y"}}, r"robot\.iP: unknown field; expected one of"),
    ({"gripper": {"type": "dynamixel"}}, r"gripper\.port: required for a dynamixel gripper"),
    ({"gripper": {"type": "xarm"}}, r"gripper\.type: an xarm gripper needs robot\.type xarm"),
    ({"gripper": {"type": "robotiq", "port": "/dev/ttyUSB0", "force": "strong"}}, r"gripper\.force: expected an integer"),
    ({"limits": {"max_step_m": -0.1}}, r"limits\.max_step_m must be a positive number"),
    ({"limits": {"workspace_min": [0, 0]}}, r"limits\.workspace_min must be three finite numbers"),
    ({"limits": {"workspace_min": [0, 0, "a"]}}, r"limits\.workspace_min\[2\]: expected a number"),
    ({"control": {"inference": "threads"}}, r"control\.inference must be 'async' or 'sync'"),
    ({"control": {"chunk_size": 2.5}}, r"control\.chunk_size: expected an integer"),
    ({"cameras": {"wrist": {"size": [240, 320]}}}, r"cameras\.wrist\.device: required field is missing"),
    ({"cameras": {"wrist": {"device": 3, "crop_fraction": 0.7}}}, r"cameras\.wrist\.crop_fraction: expected a number in \[0, 0\.5\)"),
    ({"tactile": ["left"]}, r"tactile: expected a mapping"),
    ({"tactile": {"left": {"device": 2.5}}}, r"tactile\.left\.device: expected a string or an integer, got 2\.5"),
])
def test_errors_name_the_field(patch, message):
    with pytest.raises(ConfigError, match=r"^my\.yaml: " + message):
        parse_setup({**BASE, **patch}, "my.yaml")


def test_missing_robot_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="robot: required field is missing"):
        parse_setup({})
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: [unclosed\n")
    with pytest.raises(ConfigError, match="bad.yaml: not valid YAML"):
        load_setup(bad)
    with pytest.raises(ConfigError, match="cannot read the setup file"):
        load_setup(tmp_path / "absent.yaml")


def test_check_cli(tmp_path, capsys):
    assert check_main([EXAMPLES[0]]) == 0
    assert "valid setup" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"robot": {"type": "ur"}}))
    assert check_main([str(bad)]) == 2
    assert "robot.ip: required" in capsys.readouterr().err


def test_devices_built_from_a_file(tmp_path):
    video = str(tmp_path / "gel.avi")
    w = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*"FFV1"), 25, (160, 120))
    for i in range(6):
        w.write(np.full((120, 160, 3), 90 + i, np.uint8))
    w.release()
    with FakeDynamixelServo(dxl_id=4) as dev:
        setup = tmp_path / "setup.yaml"
        setup.write_text(textwrap.dedent(f"""
            robot: {{type: ur, ip: 10.0.0.2}}
            gripper: {{type: dynamixel, port: {dev.port}, dxl_id: 4, open_position: 100, closed_position: 900}}
            tactile: {{left: {{device: {video}, background_frames: 2, size: [60, 80]}}}}
        """))
        cfg = load_setup(setup)
        gripper = build_gripper(cfg, arm=None)
        assert isinstance(gripper, DynamixelGripper)
        with gripper:
            gripper.command(0.5)
            assert dev._get_i32(116) == 500
        _, tactile = build_frame_sources(cfg)
        with tactile["left"] as gs:
            assert isinstance(gs, GelSightMini) and gs.background.shape == (60, 80, 3)


def test_build_arm_from_the_file_settings():
    from hardware.config import build_arm
    from hardware.ur import URArm
    from hardware.xarm import XArm

    arm = build_arm(parse_setup({"robot": {"type": "xarm", "ip": "1.2.3.4", "stream_hz": 150}, "control": {"rate_hz": 20}}))
    assert isinstance(arm, XArm) and (arm.ip, arm.period_s, arm.stream_hz) == ("1.2.3.4", 0.05, 150)
    ur = build_arm(parse_setup({"robot": {"type": "ur", "ip": "h", "lookahead_time": 0.05, "gain": 600}}))
    assert isinstance(ur, URArm) and (ur.period_s, ur.lookahead_time, ur.gain) == (0.1, 0.05, 600)
    with pytest.raises(ConfigError, match="'sim' is the MuJoCo scene"):
        build_arm(parse_setup({"robot": {"type": "sim"}}))
