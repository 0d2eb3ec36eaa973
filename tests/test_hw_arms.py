"""xArm and UR adapters with their SDK objects replaced at the boundary (the controllers need a real
arm or the vendor simulator, which cannot run here): command sequences, unit and orientation
conversion, error codes checked every cycle, stop order on exit, and a fault inside the control loop.
The xArm's streaming thread runs on a virtual clock that only this test's thread moves: exact points,
no sleeps."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hardware.control_loop import ControlLoop, ControlLoopConfig
from hardware.interfaces import ArmFault, HardwareError, VirtualClock
from hardware.fakes import FAKE_WORKSPACE
from hardware.safety import SafetyLimits
from hardware.ur import URArm
from hardware.xarm import XArm, XArmGripper


class StubXArmAPI:
    """Stands in for xarm.wrapper.XArmAPI: the methods the adapter uses, with the SDK's return shapes."""

    def __init__(self, pose_mm=(400.0, 0.0, 200.0, math.pi, 0.0, 0.0)):
        self.calls, self.pose = [], list(pose_mm)
        self.connected, self.err, self.warn, self.servo_code = True, 0, 0, 0
        self.gripper_pos = 850.0

    def __getattr__(self, name):  # simple commands returning code 0
        if name in ("clean_error", "clean_warn", "motion_enable", "set_mode", "set_state", "disconnect",
                    "clean_gripper_error", "set_gripper_mode", "set_gripper_enable", "set_gripper_speed"):
            return lambda *a, **k: self.calls.append((name, a, k)) or 0
        raise AttributeError(name)

    def get_err_warn_code(self):
        return 0, [self.err, self.warn]

    def get_position(self, is_radian=None):
        assert is_radian is True
        return 0, list(self.pose)

    def set_servo_cartesian(self, mvpose, is_radian=None, **kw):
        self.calls.append(("set_servo_cartesian", (list(mvpose),), {"is_radian": is_radian}))
        if self.servo_code == 0:
            self.pose = list(mvpose)
        return self.servo_code

    def set_gripper_position(self, pos, wait=False, **kw):
        self.calls.append(("set_gripper_position", (pos,), {"wait": wait}))
        self.gripper_pos = pos
        return 0

    def get_gripper_position(self):
        return 0, self.gripper_pos

    def get_gripper_err_code(self):
        return 0, 0



def names(calls):
    return [c[0] for c in calls]


def test_xarm_connect_clears_errors_enables_motion_and_servo_mode(clock):
    api = StubXArmAPI()
    with XArm("192.168.1.221", api=api, clock=clock):
        pass
    assert names(api.calls) == ["clean_error", "clean_warn", "motion_enable", "set_mode", "set_state",
                                "set_state", "disconnect"]
    assert api.calls[2][2] == {"enable": True} and api.calls[3][1] == (1,) and api.calls[4][1] == (0,)
    assert api.calls[5][1] == (4,)  # stop state on exit, before disconnecting


def test_xarm_units_and_yaw_round_trip():
    api = StubXArmAPI()
    arm = XArm("ip", api=api, stream_hz=None)
    arm.connect()
    arm.servo(np.array([0.3, -0.1, 0.25, 0.5]))
    sent = api.calls[-1][1][0]
    assert sent[:3] == pytest.approx([300.0, -100.0, 250.0])
    r = Rotation.from_euler("xyz", sent[3:])
    expected = Rotation.from_euler("z", 0.5) * Rotation.from_euler("x", math.pi)
    assert (r * expected.inv()).magnitude() == pytest.approx(0.0, abs=1e-9)
    assert arm.state().pose == pytest.approx([0.3, -0.1, 0.25, 0.5])


def test_xarm_tilted_tool_keeps_its_tilt_while_yawing():
    api = StubXArmAPI()
    arm = XArm("ip", tool_rpy=(math.pi, 0.3), api=api, stream_hz=None)
    arm.connect()
    arm.servo([0.4, 0.0, 0.2, -1.0])
    assert arm.state().pose[3] == pytest.approx(-1.0)
    r = Rotation.from_euler("xyz", api.pose[3:])
    tool_z = r.apply([0, 0, 1])
    assert math.acos(-tool_z[2]) == pytest.approx(0.3)  # tilt of the tool axis from straight down


def test_xarm_error_code_names_the_error(clock):
    api = StubXArmAPI()
    with XArm("10.0.0.7", api=api, clock=clock) as arm:
        api.err = 31
        with pytest.raises(ArmFault, match=r"xArm 10.0.0.7: controller error code 31 \(Collision Caused Abnormal Current\)"):
            arm.state()
        with pytest.raises(ArmFault, match="error code 31"):
            arm.servo([0.4, 0, 0.2, 0])
    assert "set_servo_cartesian" not in names(api.calls)


def test_xarm_warning_policy_and_api_codes():
    api = StubXArmAPI()
    arm = XArm("ip", api=api, stream_hz=None)
    arm.connect()
    api.warn = 11
    assert arm.state().warning_code == 11  # reported, not fatal by default
    strict = XArm("ip", api=api, stop_on_warning=True)
    with pytest.raises(ArmFault, match=r"warning code 11 \(Current controller cache is full\)"):
        strict.connect()
    api.warn, api.servo_code = 0, 9
    with pytest.raises(ArmFault, match="set_servo_cartesian returned API code 9"):
        arm.servo([0.4, 0, 0.2, 0])
    api.connected = False
    with pytest.raises(ArmFault, match="connection lost"):
        arm.state()


def test_xarm_fault_mid_run_stops_the_arm_in_the_loop():
    api = StubXArmAPI()

    def hold(obs):  # any callable is a policy
        return np.tile(np.r_[obs["qpos"][:4] + [0.001, 0, 0, 0], 0.0], (10, 1))

    with XArm("ip", api=api, stream_hz=None) as arm:
        loop = ControlLoop(arm, hold, config=ControlLoopConfig(inference="sync", chunk_size=10),
                           clock=VirtualClock(), limits=SafetyLimits(**FAKE_WORKSPACE))
        with pytest.raises(ArmFault, match="error code 22"):
            loop.run(max_steps=20, on_step=lambda s, o, t: s == 3 and setattr(api, "err", 22))
    n = names(api.calls)
    assert n.count("set_servo_cartesian") == 4
    last_servo = len(n) - 1 - n[::-1].index("set_servo_cartesian")
    assert n[last_servo + 1:] == ["set_state", "set_state", "disconnect"]  # loop's stop, exit's stop, close


def _streamed(api):
    return [np.array(c[1][0]) for c in list(api.calls) if c[0] == "set_servo_cartesian"]


def test_xarm_streams_small_steps_along_the_segment_and_arrives_in_one_period(clock):
    api = StubXArmAPI()
    with XArm("ip", api=api, period_s=0.5, stream_hz=20, clock=clock) as arm:
        arm.servo([0.45, 0.02, 0.2, 0.0])  # 5.4 cm from the measured (0.4, 0, 0.2), at t = 0
        clock.sleep_until(0.775)  # points every 50 ms: t = 0.05 .. 0.75
        points = _streamed(api)
    start, end = np.array([400.0, 0.0, 200.0]), np.array([450.0, 20.0, 200.0])
    alphas = [float(np.dot(p[:3] - start, end - start) / np.dot(end - start, end - start)) for p in points]
    for p, a in zip(points, alphas):
        np.testing.assert_allclose(p[:3], start + a * (end - start), atol=1e-6)  # on the straight segment
    # a tenth of the segment per point, the target reached after one period (0.5 s), then held
    assert alphas == pytest.approx([0.1 * k for k in range(1, 11)] + [1.0] * 5)


def test_xarm_new_target_starts_from_where_the_segment_has_got_to(clock):
    api = StubXArmAPI()
    with XArm("ip", api=api, period_s=0.1, stream_hz=100, clock=clock) as arm:
        arm.servo([0.5, 0.0, 0.2, 0.0])  # 10 cm in x over 0.1 s
        clock.sleep_until(0.045)  # points at 10 .. 40 ms
        arm.servo([0.4, 0.0, 0.2, 0.0])  # back: from x = 0.445 (t = 0.045) to 0.4 over the next 0.1 s
        clock.sleep_until(0.095)  # points at 50 .. 90 ms
        xs = [p[0] for p in _streamed(api)]
    back = [445 - 450 * (0.005 + 0.01 * k) for k in range(5)]  # 45 mm in 0.1 s, first point 5 ms in
    assert xs == pytest.approx([410, 420, 430, 440] + back)


def test_xarm_stream_tick_sends_the_point_for_now(clock):
    api = StubXArmAPI()
    arm = XArm("ip", api=api, period_s=0.2, stream_hz=50, clock=clock)
    arm.stream_tick()  # no target yet: nothing to send
    assert _streamed(api) == []
    api.connected = True
    arm.connect()
    arm.servo([0.5, 0.0, 0.2, 0.0])
    clock.advance(0.05)  # by hand, between two thread ticks: a quarter of the segment
    arm.stream_tick()
    assert _streamed(api)[-1][0] == pytest.approx(425.0)
    arm.close()


def test_xarm_stop_halts_the_stream_and_refuses_more_targets(clock):
    api = StubXArmAPI()
    arm = XArm("ip", api=api, period_s=0.2, stream_hz=50, clock=clock)
    arm.connect()
    arm.servo([0.5, 0.0, 0.2, 0.0])
    clock.sleep_until(0.05)
    arm.stop()
    assert len(_streamed(api)) == 2  # t = 0.02, 0.04
    clock.sleep_until(0.15)
    assert len(_streamed(api)) == 2 and names(api.calls)[-1] == "set_state"
    with pytest.raises(ArmFault, match="stopped; call connect"):
        arm.servo([0.5, 0.0, 0.2, 0.0])
    arm.connect()  # re-enables motion
    arm.servo([0.5, 0.0, 0.2, 0.0])
    arm.close()


def test_xarm_streaming_error_code_surfaces_on_the_next_cycle(clock):
    api = StubXArmAPI()
    with XArm("ip", api=api, period_s=0.2, stream_hz=50, clock=clock) as arm:
        api.servo_code = 9
        arm.servo([0.41, 0.0, 0.2, 0.0])
        arm.state()  # no point streamed yet
        clock.sleep_until(0.03)  # the first point went at t = 0.02
        with pytest.raises(ArmFault, match="set_servo_cartesian returned API code 9 while streaming"):
            arm.state()


def test_xarm_gripper_maps_closing_to_sdk_units():
    api = StubXArmAPI()
    arm = XArm("ip", api=api, stream_hz=None)
    arm.connect()
    g = XArmGripper(arm)
    g.connect()
    g.command(0.25)
    assert api.calls[-1] == ("set_gripper_position", (637.5,), {"wait": False})
    assert g.state().position == pytest.approx(0.25)
    g.command(1.0)
    assert api.gripper_pos == 0.0
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        g.command(-0.1)
    with pytest.raises(HardwareError, match="connect the arm first"):
        XArmGripper(XArm("ip")).connect()


class StubRTDE:
    """Stands in for RTDEControlInterface + RTDEReceiveInterface (one object plays both)."""

    def __init__(self, tcp=(0.4, 0.0, 0.2, math.pi, 0.0, 0.0)):
        self.calls, self.tcp = [], list(tcp)
        self.connected, self.program_running, self.protective, self.estop, self.safety_mode = True, True, False, False, 1

    def isConnected(self):
        return self.connected

    def isProgramRunning(self):
        return self.program_running

    def isProtectiveStopped(self):
        return self.protective

    def isEmergencyStopped(self):
        return self.estop

    def getSafetyMode(self):
        return self.safety_mode

    def getActualTCPPose(self):
        return list(self.tcp)

    def servoL(self, pose, speed, acc, time, lookahead, gain):
        self.calls.append(("servoL", list(pose), time, lookahead, gain))
        self.tcp = list(pose)
        return True

    def servoStop(self, a=10.0):
        self.calls.append(("servoStop",))
        return True

    def stopScript(self):
        self.calls.append(("stopScript",))

    def disconnect(self):
        self.calls.append(("disconnect",))


def test_ur_servol_arguments_and_tcp_round_trip():
    rtde = StubRTDE()
    arm = URArm("192.168.1.10", period_s=0.1, lookahead_time=0.05, gain=500, control=rtde, receive=rtde)
    arm.connect()
    arm.servo([0.35, 0.05, 0.3, 0.7])
    _, pose, t, lookahead, gain = rtde.calls[-1]
    assert pose[:3] == pytest.approx([0.35, 0.05, 0.3]) and (t, lookahead, gain) == (0.1, 0.05, 500)
    r = Rotation.from_rotvec(pose[3:])
    expected = Rotation.from_euler("z", 0.7) * Rotation.from_rotvec([math.pi, 0, 0])
    assert (r * expected.inv()).magnitude() == pytest.approx(0.0, abs=1e-9)
    assert arm.state().pose == pytest.approx([0.35, 0.05, 0.3, 0.7])


def test_ur_exit_calls_servostop_then_stopscript():
    rtde = StubRTDE()
    with URArm("ip", control=rtde, receive=rtde) as arm:
        arm.servo([0.4, 0, 0.2, 0])
    assert [c[0] for c in rtde.calls] == ["servoL", "servoStop", "stopScript", "disconnect", "disconnect"]


@pytest.mark.parametrize("fault, match", [
    (dict(protective=True), "protective stop"), (dict(estop=True), "emergency stop is active"),
    (dict(safety_mode=5), r"safety mode 5 \(safeguard stop\)"), (dict(program_running=False), "control script is not running"),
    (dict(connected=False), "RTDE connection lost"),
])
def test_ur_faults_are_named_and_stop_the_loop(fault, match):
    rtde = StubRTDE()

    def hold(obs):
        return np.tile(np.r_[obs["qpos"][:4], 1.0], (5, 1))

    arm = URArm("ip", control=rtde, receive=rtde)
    arm.connect()
    loop = ControlLoop(arm, hold, config=ControlLoopConfig(inference="sync", chunk_size=5), clock=VirtualClock(),
                       limits=SafetyLimits(**FAKE_WORKSPACE))

    def inject(step, obs, target):
        if step == 2:
            for k, v in fault.items():
                setattr(rtde, k, v)
        return False

    with pytest.raises(ArmFault, match=match):
        loop.run(max_steps=10, on_step=inject)
    kinds = [c[0] for c in rtde.calls]
    assert kinds.count("servoL") == 3 and kinds[-1] == "servoStop"


def test_ur_sdk_runtime_errors_are_arm_faults_naming_the_call_and_stop_the_loop():
    """ur-rtde raises its C++ exceptions as RuntimeError (a connection dropped mid-call): an ArmFault naming the
    call, so the run ends as a device fault (exit 1), never a traceback."""
    rtde = StubRTDE()

    def dropped(*args):
        raise RuntimeError("RTDE control script is not running or connection lost")

    arm = URArm("10.0.0.5", control=rtde, receive=rtde)
    arm.connect()
    rtde.servoL = dropped
    with pytest.raises(ArmFault, match=r"^UR 10\.0\.0\.5: servoL: RTDE control script is not running"):
        arm.servo([0.4, 0.0, 0.2, 0.0])
    rtde.getActualTCPPose = dropped
    with pytest.raises(ArmFault, match=r"^UR 10\.0\.0\.5: reading the pose: "):
        arm.state()
    rtde.servoStop = dropped
    with pytest.raises(ArmFault, match=r"^UR 10\.0\.0\.5: servoStop: "):
        arm.stop()


def test_ur_reduced_mode_still_moves():
    # reduced mode (safety mode 2: the controller's slower, safety-limited mode) is not a fault: state is
    # read and every target still reaches servoL with the configured timing; only the other modes stop
    rtde = StubRTDE()
    rtde.safety_mode = 2
    arm = URArm("ip", period_s=0.1, lookahead_time=0.05, gain=400, control=rtde, receive=rtde)
    arm.connect()
    assert arm.state().pose == pytest.approx([0.4, 0.0, 0.2, 0.0])
    arm.servo([0.42, -0.01, 0.25, 0.3])
    arm.servo([0.43, -0.02, 0.26, 0.35])
    assert [c[0] for c in rtde.calls] == ["servoL", "servoL"]
    for call, (x, y, z, yaw) in zip(rtde.calls, [(0.42, -0.01, 0.25, 0.3), (0.43, -0.02, 0.26, 0.35)]):
        _, pose, t, lookahead, gain = call
        assert pose[:3] == pytest.approx([x, y, z]) and (t, lookahead, gain) == (0.1, 0.05, 400)
        r = Rotation.from_rotvec(pose[3:]) * (Rotation.from_euler("z", yaw) * Rotation.from_rotvec([math.pi, 0, 0])).inv()
        assert r.magnitude() == pytest.approx(0.0, abs=1e-9)
    assert arm.state().pose == pytest.approx([0.43, -0.02, 0.26, 0.35])
    rtde.safety_mode = 3  # protective stop: now it is a fault and nothing more is sent
    with pytest.raises(ArmFault, match=r"safety mode 3 \(protective stop\)"):
        arm.servo([0.44, -0.02, 0.26, 0.35])
    assert [c[0] for c in rtde.calls] == ["servoL", "servoL"]


def test_a_tool_tilted_from_its_configured_orientation_is_a_fault_before_any_motion():
    """The commands say [x, y, z, yaw] about a fixed tool orientation: a tool tilted 20 deg from it (or a setting
    in the wrong units) would be turned by all of it within one period. The loop stops the arm instead."""
    tilted = Rotation.from_euler("y", 0.35) * Rotation.from_euler("x", math.pi)  # 20 deg off straight down
    api = StubXArmAPI(pose_mm=(400.0, 0.0, 200.0, *tilted.as_euler("xyz")))
    arm = XArm("ip", api=api, stream_hz=None)
    arm.connect()
    with pytest.raises(ArmFault, match=r"the tool is tilted 20\.1 deg from the orientation tool_rpy configures"):
        ControlLoop(arm, lambda obs: np.tile([0.4, 0.0, 0.2, 0.0, 0.0], (5, 1)), limits=SafetyLimits(**FAKE_WORKSPACE),
                    config=ControlLoopConfig(inference="sync", chunk_size=5), clock=VirtualClock()).run(max_steps=3)
    assert "set_servo_cartesian" not in names(api.calls)
    rtde = StubRTDE()
    rtde.tcp = [0.4, 0.0, 0.2, *(Rotation.from_euler("z", 0.4) * Rotation.from_euler("x", math.pi - 0.1)).as_rotvec()]
    with pytest.raises(ArmFault, match=r"tilted 5\.7 deg from the orientation tool_rotvec configures"):
        URArm("ip", control=rtde, receive=rtde).state()
    rtde.tcp[3:] = (Rotation.from_euler("z", 0.4) * Rotation.from_euler("x", math.pi - 0.05)).as_rotvec()
    assert URArm("ip", control=rtde, receive=rtde).state().pose[3] == pytest.approx(0.4, abs=0.01)  # 2.9 deg: within


@pytest.mark.parametrize("kwargs, field", [(dict(lookahead_time=0.5), "lookahead_time"), (dict(gain=50), "gain"),
                                           (dict(period_s=0), "period_s")])
def test_ur_bad_settings(kwargs, field):
    with pytest.raises(ValueError, match=field):
        URArm("ip", **kwargs)
