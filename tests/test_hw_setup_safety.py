"""A robot never starts with an unsafe setup.

Physically implausible setups are refused per robot type (reach, height, speed and rotation per
control period, gripper ranges and IDs, addresses, rates), in the file check and again when devices
are built; an unreachable controller is one line naming the address and the setup file. The SDK
objects are replaced at the boundary (fake ``xarm.wrapper`` / ``rtde_receive`` modules); the only
real socket touched is a closed port on 127.0.0.1.
"""

import socket
import sys
import types

import pytest
import yaml

from hardware import config as hwconfig
from hardware.check import main as check_main
from hardware.config import (ARM_MODELS, ConfigError, SetupConfig, build_arm, build_gripper, load_setup,
                             open_setup, parse_setup)
from hardware.interfaces import ArmFault, HardwareError
from hardware.ur import URArm
from hardware.xarm import XArm

BOX = {"workspace_min": [0.25, -0.25, 0.02], "workspace_max": [0.6, 0.25, 0.4]}
XARM = {"robot": {"type": "xarm", "ip": "10.0.0.2"}, "limits": BOX}
UR5 = {"robot": {"type": "ur", "ip": "10.0.0.2", "model": "ur5"}, "limits": BOX}


def limits(**kw):
    return {"limits": {**BOX, **kw}}


def with_(base, **sections):
    return {**base, **sections}


@pytest.mark.parametrize("setup, message", [
    # reach and height, per arm model
    (with_(XARM, **limits(workspace_min=[-1.5, -1.5, 0.02], workspace_max=[1.5, 1.5, 0.4])),
     r"limits\.workspace_max: the box corner \[1\.5, 1\.5\] is 2\.12 m from the base axis, beyond the "
     r"reach of an xArm 5/6/7 \(0\.7 m\): every corner of workspace_min\.\.workspace_max must lie within 0\.7 m"),
    (with_(XARM, **limits(workspace_max=[0.8, 0.25, 0.4])), r"limits\.workspace_max: the box corner \[0\.8, 0\.25\] is 0\.84 m"),
    (with_(XARM, **limits(workspace_max=[0.5, 0.25, 1.5])),
     r"limits\.workspace_max: z = 1\.5 m is above the highest point an xArm 5/6/7 reaches \(0\.95 m above its base\)"),
    (with_(UR5, robot={"type": "ur", "ip": "10.0.0.2", "model": "ur3"}, **limits(workspace_max=[0.6, 0.25, 0.4])),
     r"limits\.workspace_max: .* beyond the reach of a UR3 \(0\.5 m\)"),
    (with_(XARM, **limits(workspace_min=[0.25, -0.25, -0.5])),
     r"limits\.workspace_min: z = -0\.5 m is below the robot's base plane \(z = 0, its mounting surface\); "
     r"the box must start at z >= 0"),
    # speed and rotation per control period, in m/s and rad/s
    (with_(XARM, **limits(max_step_m=0.05)),
     r"limits\.max_step_m: 0\.05 m per period at control\.rate_hz 10 is 0\.5 m/s; at most 0\.25 m/s "
     r"\(max_step_m <= 0\.025 at 10 Hz\)"),
    (with_(XARM, **limits(max_rotation_rad=0.2)),
     r"limits\.max_rotation_rad: 0\.2 rad per period at control\.rate_hz 10 is 2 rad/s; at most 1 rad/s "
     r"\(max_rotation_rad <= 0\.1 at 10 Hz\)"),
    (with_(XARM, control={"rate_hz": 20}),  # the default 0.02 m per period is 0.4 m/s at 20 Hz
     r"limits\.max_step_m: 0\.02 m per period at control\.rate_hz 20 is 0\.4 m/s; at most 0\.25 m/s "
     r"\(max_step_m <= 0\.0125 at 20 Hz\)"),
    # rates and deadlines
    (with_(XARM, control={"rate_hz": 200}), r"control\.rate_hz: a robot's control rate is at most 100 Hz \(got 200\)"),
    (with_(XARM, robot={"type": "xarm", "ip": "10.0.0.2", "stream_hz": 20}, control={"rate_hz": 25},
           **limits(max_step_m=0.01, max_rotation_rad=0.04)),
     r"robot\.stream_hz: must be at least control\.rate_hz \(25\) \(got 20\.0\)"),
    (with_(XARM, control={"chunk_size": 20}),  # the policy's (its checkpoint), checked against it at deployment
     r"control\.chunk_size: the chunk size is the policy's: deployment takes it from the checkpoint"),
    (with_(XARM, cameras={"wrist": {"device": 0, "fps": 500}}), r"cameras\.wrist\.fps: Input should be less than or equal to 240"),
    # the watchdog: a window that catches a silent thread, and frames fresher than it
    (with_(XARM, control={"stale_after_periods": 1e6}),
     r"control\.stale_after_periods: 1e\+06 periods at 10 Hz is 1e\+05 s without a command or frame before the arm "
     r"stops; at most 0\.5 s \(got 1000000\.0\)"),
    (with_(XARM, control={"stale_after_periods": 0.5}),
     r"control\.stale_after_periods: at least 1\.5: below, the watchdog trips between two commands sent on time"),
    (with_(XARM, tactile={"left": {"fps": 1}}),
     r"tactile\.left\.fps: a frame every 1 s: at most half the watchdog's 0\.2 s window"),
    (with_(XARM, cameras={"wrist": {"device": 0, "fps": 9}}), r"cameras\.wrist\.fps: a frame every 0\.111 s: at most half"),
    (with_(XARM, cameras={"wrist": {"device": 0, "size": [240, 100000]}}),
     r"cameras\.wrist\.size\[1\]: Input should be less than or equal to 4096"),
    # addresses and models, per robot type
    (with_(XARM, robot={"type": "xarm", "ip": "0.0.0.0"}), r"robot\.ip: not a controller's address .* \(got '0\.0\.0\.0'\)"),
    (with_(XARM, robot={"type": "xarm", "ip": "224.0.0.1"}), r"robot\.ip: not a controller's address .* \(got '224\.0\.0\.1'\)"),
    (with_(XARM, robot={"type": "xarm", "ip": "255.255.255.255"}), r"robot\.ip: not a controller's address .* \(got '255\.255\.255\.255'\)"),
    (with_(XARM, robot={"type": "xarm", "ip": "fe80::1"}),
     r"robot\.ip: the xArm SDK connects over IPv4 only: expected an address such as 192\.168\.1\.221 \(got 'fe80::1'\)"),
    (with_(UR5, robot={"type": "ur", "ip": "10.0.0.2"}),
     r"robot\.model: required for a UR arm \(its reach bounds the workspace\): one of ur3, ur3e, ur5, ur5e"),
    (with_(XARM, robot={"type": "xarm", "ip": "10.0.0.2", "model": "ur5"}),
     r"robot\.model: not an xarm model: one of xarm5, xarm6, xarm7 \(got 'ur5'\)"),
    (with_(XARM, robot={"type": "xarm", "ip": "10.0.0.2", "model": "kr6"}), r"robot\.model: Input should be"),
    (with_(XARM, robot={"type": "xarm", "ip": "10.0.0.2", "tool_rotvec": [3.1, 0, 0]}),
     r"robot\.tool_rotvec: not used by an xarm robot \(its fields: ip, model, tool_rpy, stream_hz, stop_on_warning\)"),
    # grippers
    (with_(UR5, gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "force": 1000}), r"gripper\.force: Input should be less than or equal to 255"),
    (with_(UR5, gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "speed": -5}), r"gripper\.speed: Input should be greater than or equal to 0"),
    (with_(UR5, gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "slave_id": 0}), r"gripper\.slave_id: Input should be greater than or equal to 1"),
    (with_(UR5, gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "slave_id": 248}), r"gripper\.slave_id: Input should be less than or equal to 247"),
    (with_(UR5, gripper={"type": "robotiq", "port": "/dev/ttyUSB0", "dxl_id": 3}),
     r"gripper\.dxl_id: not used by a robotiq gripper \(its fields: port, baudrate, slave_id, speed, force\)"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "open_position": 2048, "closed_position": 2048}),
     r"gripper\.closed_position: must differ from open_position"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "open_position": 2048, "closed_position": 5000}),
     r"gripper\.closed_position: a Dynamixel Goal Position within one turn is 0\.\.4095 ticks \(got 5000\)"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "open_position": -1, "closed_position": 3000}),
     r"gripper\.open_position: a Dynamixel Goal Position within one turn is 0\.\.4095 ticks \(got -1\)"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "open_position": 2048.5, "closed_position": 3000}),
     r"gripper\.open_position: Goal Position ticks are whole numbers \(got 2048\.5\)"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "dxl_id": 253, "open_position": 1, "closed_position": 3}),
     r"gripper\.dxl_id: Input should be less than or equal to 252"),
    (with_(UR5, gripper={"type": "dynamixel", "port": "/dev/ttyUSB0", "goal_current": 0, "open_position": 1, "closed_position": 3}),
     r"gripper\.goal_current: Input should be greater than 0"),
    (with_(XARM, gripper={"type": "xarm", "open_position": 900, "closed_position": 0}),
     r"gripper\.open_position: an xArm gripper position is 0\.\.850 \(SDK units\) \(got 900\)"),
    (with_(XARM, gripper={"type": "xarm", "open_position": 400, "closed_position": 400}), r"gripper\.closed_position: must differ"),
    (with_(XARM, gripper={"type": "xarm", "speed": 0}), r"gripper\.speed: an xArm gripper speed is 1\.\.5000 \(r/min\) \(got 0\)"),
    (with_(XARM, gripper={"type": "xarm", "force": 10}), r"gripper\.force: not used by an xarm gripper"),
    (with_(XARM, **limits(gripper_min=0.5, gripper_max=0.5)), r"limits\.gripper_min: must be below gripper_max"),
])
def test_implausible_setups_are_refused(setup, message):
    with pytest.raises(ConfigError, match=r"^my\.yaml: " + message) as info:
        parse_setup(setup, "my.yaml")
    assert "\n" not in str(info.value)


def test_reach_is_per_arm_model():
    far = limits(workspace_min=[0.3, -0.3, 0.1], workspace_max=[1.0, 0.3, 0.8])  # 1.04 m out, 0.8 m up
    with pytest.raises(ConfigError, match="reach of a UR5"):
        parse_setup(with_(UR5, **far))
    assert parse_setup(with_(UR5, robot={"type": "ur", "ip": "10.0.0.2", "model": "ur10e"}, **far)).limits == \
        parse_setup(with_(UR5, robot={"type": "ur", "ip": "10.0.0.2", "model": "ur10"}, **far)).limits
    assert {"xarm5", "xarm6", "xarm7", "ur3", "ur5", "ur10"} <= set(ARM_MODELS)
    assert ARM_MODELS["xarm7"].reach_m == 0.7 and ARM_MODELS["ur5"].reach_m == 0.85 and ARM_MODELS["ur3"].reach_m == 0.5


def test_speed_bound_follows_the_control_rate():
    slow = parse_setup(with_(XARM, control={"rate_hz": 20}, **limits(max_step_m=0.0125, max_rotation_rad=0.05)))
    assert slow.control.rate_hz == 20
    # the same per-period step is fine at 5 Hz (0.1 m/s), refused at 25 Hz (0.5 m/s)
    assert parse_setup(with_(XARM, control={"rate_hz": 5}, **limits(max_step_m=0.02))).limits.max_step_m == 0.02
    with pytest.raises(ConfigError, match="limits.max_step_m: 0.02 m per period at control.rate_hz 25"):
        parse_setup(with_(XARM, control={"rate_hz": 25}, **limits(max_step_m=0.02, max_rotation_rad=0.04)))


def test_all_physical_problems_on_one_line():
    with pytest.raises(ConfigError) as info:
        parse_setup(with_(XARM, **limits(workspace_min=[0.25, -0.25, -0.1], max_step_m=0.05)), "my.yaml")
    msg = str(info.value)
    assert msg.startswith("my.yaml: limits.workspace_min: z = -0.1 m") and "; limits.max_step_m: 0.05 m" in msg
    assert "\n" not in msg


@pytest.mark.parametrize("text, message", [
    ("robot: {type: xarm, ip: 10.0.0.2, tool_rpy: [.nan, 0]}\n", r"robot\.tool_rpy\[0\]: Input should be a finite number"),
    ("robot: {type: xarm, ip: 10.0.0.2, stream_hz: .inf}\n", r"robot\.stream_hz: Input should be a finite number"),
    ("robot: {type: ur, ip: 10.0.0.2, model: ur5, tool_rotvec: [0, -.inf, 0]}\n", r"robot\.tool_rotvec\[1\]: Input should be a finite"),
    ("robot: {type: xarm, ip: 10.0.0.2}\ncontrol: {inference_deadline_s: .nan}\n", r"control\.inference_deadline_s: Input should be a finite"),
])
def test_nan_and_inf_in_the_file_are_refused(tmp_path, text, message):
    path = tmp_path / "nan.yaml"
    path.write_text(text + "limits: {workspace_min: [0.25, -0.25, 0.02], workspace_max: [0.6, 0.25, 0.4]}\n")
    with pytest.raises(ConfigError, match=r"nan\.yaml: " + message):
        load_setup(path)


def test_check_cli_refuses_an_implausible_file_in_one_line(tmp_path, capsys):
    path = tmp_path / "far.yaml"
    path.write_text(yaml.safe_dump(with_(XARM, **limits(workspace_min=[-1.5, -1.5, 0.0], workspace_max=[1.5, 1.5, 0.4]))))
    assert check_main([str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"{path}: limits.workspace_max: the box corner" in err
    assert err.startswith("python -m hardware.check: error: invalid setup: ")


# -- nothing is built from an unvalidated config -----------------------------------------------------

def unchecked(cls, **values):
    """An instance of the (frozen, pydantic) dataclass ``cls`` holding ``values``, built without validation."""
    obj = cls.__new__(cls)
    for k, v in values.items():
        object.__setattr__(obj, k, v)
    return obj


def unvalidated(**limits_kw):
    """A SetupConfig that skipped validation, with a ±1.5 m box and a 5 m step."""
    good = parse_setup(XARM)
    bad_limits = unchecked(type(good.limits), **{**vars(good.limits), **limits_kw})
    return unchecked(SetupConfig, **{**vars(good), "limits": bad_limits})


class RecordingSDK(types.ModuleType):
    """A fake ``xarm.wrapper`` module: records every XArmAPI construction, and fails it like the SDK does."""

    def __init__(self):
        super().__init__("xarm.wrapper")
        self.made = []
        outer = self

        class XArmAPI:
            def __init__(self, ip, **kw):
                outer.made.append(ip)
                raise Exception("connect socket failed")  # what xarm-python-sdk raises when nothing answers

        self.XArmAPI = XArmAPI


@pytest.fixture
def fake_xarm_sdk(monkeypatch):
    sdk = RecordingSDK()
    monkeypatch.setitem(sys.modules, "xarm.wrapper", sdk)
    monkeypatch.setattr(hwconfig, "CONNECT_TIMEOUT_S", None, raising=True)  # no pre-flight: reach the SDK
    return sdk


def test_devices_are_never_built_from_an_unvalidated_config(fake_xarm_sdk):
    cfg = unvalidated(workspace_min=(-1.5, -1.5, 0.02), workspace_max=(1.5, 1.5, 0.4))
    for build in (lambda: build_arm(cfg), lambda: build_gripper(cfg, arm=None), lambda: open_setup(cfg).__enter__()):
        with pytest.raises(ConfigError, match=r"^setup: limits\.workspace_max: the box corner"):
            build()
    with pytest.raises(ConfigError, match=r"^setup: limits\.max_step_m: Input should be less than or equal to 0\.1 \(got 5\.0\)"):
        open_setup(unvalidated(max_step_m=5.0)).__enter__()
    with pytest.raises(ConfigError, match="expected a SetupConfig from load_setup"):
        build_arm(XARM)
    assert fake_xarm_sdk.made == []  # nothing tried to connect


def test_open_setup_revalidates_with_the_file_name(tmp_path, fake_xarm_sdk):
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(XARM))
    cfg = load_setup(path)
    tampered = unchecked(SetupConfig, **{**vars(cfg), "control": unchecked(type(cfg.control), **{**vars(cfg.control),
                                                                                          "rate_hz": 10000.0})})
    assert tampered.source == str(path)
    with pytest.raises(ConfigError, match=rf"^{path}: control\.rate_hz"):
        open_setup(tampered).__enter__()
    assert fake_xarm_sdk.made == []


# -- an unreachable robot: one line naming the address and the file --------------------------------

def test_xarm_sdk_connection_failure_names_the_address(fake_xarm_sdk):
    arm = XArm("127.0.0.1", connect_timeout_s=None)
    with pytest.raises(ArmFault, match=r"^xArm 127\.0\.0\.1: cannot connect to the controller \(connect socket failed\); "
                                       r"check that it is powered on and reachable at 127\.0\.0\.1") as info:
        arm.connect()
    assert info.value.__cause__ is None and fake_xarm_sdk.made == ["127.0.0.1"]


def test_ur_sdk_connection_failure_names_the_address(monkeypatch):
    def refuse(ip, *a, **k):
        raise RuntimeError("Failed to connect to RTDE")  # what ur_rtde raises

    monkeypatch.setitem(sys.modules, "rtde_receive", types.SimpleNamespace(RTDEReceiveInterface=refuse))
    monkeypatch.setitem(sys.modules, "rtde_control", types.SimpleNamespace(RTDEControlInterface=refuse))
    with pytest.raises(ArmFault, match=r"^UR 127\.0\.0\.1: cannot connect to the controller \(Failed to connect to RTDE\)"):
        URArm("127.0.0.1", connect_timeout_s=None).connect()


def closed_loopback_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now: a connection is refused at once
    return port


@pytest.mark.parametrize("make", [lambda port: XArm("127.0.0.1", port=port), lambda port: URArm("127.0.0.1", port=port)])
def test_preflight_refuses_an_address_where_nothing_answers(monkeypatch, make):
    sdk = RecordingSDK()
    made = []  # the UR SDK's interfaces constructed: none may be, the address answers nothing
    monkeypatch.setitem(sys.modules, "xarm.wrapper", sdk)
    for name in ("rtde_receive", "rtde_control"):
        interface = "RTDEReceiveInterface" if name == "rtde_receive" else "RTDEControlInterface"
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**{interface: made.append}))
    port = closed_loopback_port()
    with pytest.raises(ArmFault, match=rf"127\.0\.0\.1: cannot connect to the controller \(nothing answers on TCP port "
                                       rf"{port}: .*\); check that it is powered on and reachable at 127\.0\.0\.1"):
        make(port).connect()
    assert sdk.made == [] and made == []


def test_preflight_timeout_is_bounded(monkeypatch):
    seen = {}

    def black_hole(address, timeout=None):
        seen["timeout"] = timeout
        raise socket.timeout("timed out")

    monkeypatch.setattr(socket, "create_connection", black_hole)
    with pytest.raises(ArmFault, match=r"nothing answers on TCP port 30004 within 2\.5 s"):
        URArm("127.0.0.1", connect_timeout_s=2.5).connect()
    assert seen["timeout"] == 2.5


def test_open_setup_connection_failure_names_the_file_and_address(tmp_path, fake_xarm_sdk):
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(with_(XARM, robot={"type": "xarm", "ip": "127.0.0.1"})))
    with pytest.raises(HardwareError, match=rf"^{path}: xArm 127\.0\.0\.1: cannot connect to the controller"):
        with open_setup(load_setup(path)):
            pass


def test_check_cli_connect_failure_is_one_line_exit_1(tmp_path, capsys, fake_xarm_sdk):
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(with_(XARM, robot={"type": "xarm", "ip": "127.0.0.1"})))
    assert check_main([str(path), "--connect", "--seconds", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert err.startswith(f"python -m hardware.check: error: device check failed: {path}: xArm 127.0.0.1: cannot connect to the controller (connect socket failed)")


def test_deploy_on_robot_fails_on_an_unreachable_arm_naming_file_and_address(tmp_path, fake_xarm_sdk):
    import torch
    from act_fixtures import tiny_config

    from controltac_il.app.deploy import deploy_on_robot
    from policies.act import ACT, save_checkpoint

    torch.manual_seed(0)
    checkpoint = save_checkpoint(tmp_path / "ckpt", ACT(tiny_config()))
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(with_(XARM, robot={"type": "xarm", "ip": "127.0.0.1"},
                                         cameras={"third_view": {"device": 0}, "wrist": {"device": 1}},
                                         tactile={"left": {"device": 2}, "right": {"device": 3}})))
    with pytest.raises(HardwareError, match=rf"^{path}: xArm 127\.0\.0\.1: cannot connect to the controller \(connect socket failed\)"):
        deploy_on_robot("xarm", checkpoint, path)
    assert fake_xarm_sdk.made == ["127.0.0.1"]


@pytest.mark.parametrize("setup, message", [
    (with_(XARM, control={"rate_hz": 10000}), r"control\.rate_hz: a robot's control rate is at most 100 Hz \(got 10000\)$"),
    (with_(UR5, gripper={"type": "dynamixel", "baudrate": 57600}),
     r"gripper\.port: required for a dynamixel gripper .*; gripper\.open_position: open_position and closed_position"),
])
def test_every_problem_names_its_own_field(setup, message):
    with pytest.raises(ConfigError, match=r"^my\.yaml: " + message):
        parse_setup(setup, "my.yaml")


def test_a_missing_serial_gripper_port_is_a_hardware_error(tmp_path):
    from hardware.dynamixel import DynamixelGripper
    from hardware.robotiq import RobotiqGripper

    port = str(tmp_path / "no-such-adapter")
    with pytest.raises(HardwareError, match=rf"robotiq on {port}: cannot open the port"):
        RobotiqGripper(port).connect()
    with pytest.raises(HardwareError, match=rf"dynamixel id 1 on {port}: cannot open"):
        DynamixelGripper(port).connect()
