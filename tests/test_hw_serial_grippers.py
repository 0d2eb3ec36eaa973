"""Dynamixel and Robotiq grippers through the real client stacks (dynamixel_sdk / pyserial) against
emulated devices on a pseudo-terminal: register writes, positions, CRC both ways, faults, garbage.

The emulated fingers move on a virtual clock that the tests advance, so nothing waits for them; the
only wall-clock waits left are serial read timeouts where a test wants no reply (a silent device, a
frame with a bad CRC, garbage). dynamixel_sdk's reply timeout is raised for a loaded machine
(conftest's ``dynamixel_latency``)."""

import pytest
import serial

from hardware.dynamixel import (
    ADDR_GOAL_CURRENT,
    ADDR_OPERATING_MODE,
    ADDR_TORQUE_ENABLE,
    DynamixelGripper,
)
from hardware.fakes import FAKE_WORKSPACE
from hardware.fake_serial import FakeDynamixelServo, FakeRobotiq2F85, dxl_crc
from hardware.interfaces import HardwareError, VirtualClock
from hardware.robotiq import RobotiqGripper, crc16_modbus

pytestmark = pytest.mark.usefixtures("dynamixel_latency")


# -- CRCs against frames printed in the vendors' manuals --------------------------------------------

@pytest.mark.parametrize("frame", [
    "09 10 03 E8 00 03 06 09 00 00 00 FF FF 72 19",  # Robotiq manual: open at full speed and force
    "09 10 03 E8 00 03 06 01 00 00 00 00 00 72 E1",  # activate
    "09 10 03 E8 00 03 01 30",  # write response
    "09 04 07 D0 00 03 B1 CE",  # read status request
])
def test_crc16_modbus_matches_robotiq_manual(frame):
    b = bytes.fromhex(frame)
    assert crc16_modbus(b[:-2]).to_bytes(2, "little") == b[-2:]


def test_dxl_crc_matches_protocol_2_ping_example():
    # e-manual Protocol 2.0 ping instruction to ID 1: FF FF FD 00 01 03 00 01 19 4E
    b = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    assert dxl_crc(b[:-2]).to_bytes(2, "little") == b[-2:]


# -- Dynamixel ------------------------------------------------------------------------------------

def test_dynamixel_connect_sets_current_based_position_mode():
    with FakeDynamixelServo(dxl_id=3) as dev:
        g = DynamixelGripper(dev.port, dxl_id=3, goal_current=250)
        g.connect()
        try:
            assert g.model_number == FakeDynamixelServo.MODEL_XM430_W350
            # torque off before the EEPROM operating mode, then mode 5, goal current, torque on last
            addrs = [a for a, _ in dev.writes]
            assert addrs.index(ADDR_TORQUE_ENABLE) < addrs.index(ADDR_OPERATING_MODE)
            assert dev.table[ADDR_OPERATING_MODE] == 5 and dev.table[ADDR_TORQUE_ENABLE] == 1
            assert int.from_bytes(dev.table[ADDR_GOAL_CURRENT:ADDR_GOAL_CURRENT + 2], "little") == 250
            assert dev.writes[-1] == (ADDR_TORQUE_ENABLE, b"\x01")
        finally:
            g.close()


def test_dynamixel_positions_map_to_closing_fraction_with_negative_ticks():
    clock = VirtualClock()
    with FakeDynamixelServo(start_position=-500, speed_ticks_s=20000.0, clock=clock) as dev:
        with DynamixelGripper(dev.port, open_position=-500, closed_position=1500, clock=clock) as g:
            assert g.state().position == pytest.approx(0.0)
            g.command(0.25)
            assert dev._get_i32(116) == 0  # -500 + 0.25 * 2000
            g.command(1.0)
            clock.advance(0.05)  # 1000 of the 2000 ticks at 20000 ticks/s
            assert g.state().position == pytest.approx(0.5)
            assert g.state().timestamp == 0.05
            clock.advance(0.05)
            assert g.state().position == pytest.approx(1.0)
            g.command(0.0)
            clock.advance(0.1)
            assert g.state().position == pytest.approx(0.0)
            dev.object_at = 700
            g.command(1.0)  # closes on the object: stops at 700 ticks = 0.6, squeezing at the goal current
            clock.advance(0.1)
            assert g.state().position == pytest.approx(0.6)
            assert g.present_current() == g.goal_current


def test_dynamixel_garbage_reply_is_retried_then_reported():
    with FakeDynamixelServo() as dev:
        with DynamixelGripper(dev.port, retries=1) as g:
            dev.garbage_replies = 1
            g.state()  # one corrupted reply: the retry succeeds
            dev.garbage_replies = 2
            with pytest.raises(HardwareError, match=r"dynamixel id 1 on .*: present position failed: .*status packet"):
                g.state()


def test_dynamixel_hardware_error_is_decoded():
    with FakeDynamixelServo() as dev:
        with DynamixelGripper(dev.port) as g:
            dev.hardware_error = 0x24  # overheating + overload
            with pytest.raises(HardwareError, match=r"hardware error status 0x24 \(overheating, overload\)"):
                g.command(0.5)


def test_dynamixel_silent_servo_and_wrong_id():
    with FakeDynamixelServo(dxl_id=1) as dev:
        g = DynamixelGripper(dev.port, dxl_id=2, retries=0)
        with pytest.raises(HardwareError, match="dynamixel id 2 .*: ping failed: .*no status packet"):
            g.connect()
        g.close()


def test_a_connect_that_fails_in_a_with_block_releases_the_port():
    """A with-block never exits a failed enter: the gripper closes the port its connect opened before raising."""
    with FakeDynamixelServo(dxl_id=1) as dev:
        g = DynamixelGripper(dev.port, dxl_id=2, retries=0)
        with pytest.raises(HardwareError, match="ping failed"):
            with g:
                pass
        assert g._port is None


def test_fake_servo_answers_a_bad_crc_with_the_crc_error():
    with FakeDynamixelServo() as dev:
        ping = bytearray.fromhex("FF FF FD 00 01 03 00 01 19 4E")
        ping[-1] ^= 0xFF
        with serial.Serial(dev.port, 57600, timeout=0.5) as s:
            s.write(bytes(ping))
            reply = s.read(11)
        assert reply[8] == 0x03 and dev.crc_errors == 1  # status error field: CRC error
        assert dxl_crc(reply[:-2]) == int.from_bytes(reply[-2:], "little")


@pytest.mark.parametrize("kwargs, field", [(dict(dxl_id=300), "dxl_id"), (dict(open_position=5, closed_position=5), "open_position"),
                                           (dict(goal_current=0), "goal_current")])
def test_dynamixel_bad_config(kwargs, field):
    with pytest.raises(ValueError, match=field):
        DynamixelGripper("/dev/null", **kwargs)


def test_dynamixel_command_out_of_range():
    with FakeDynamixelServo() as dev, DynamixelGripper(dev.port) as g:
        with pytest.raises(ValueError, match=r"\[0, 1\]"):
            g.command(1.2)


# -- Robotiq --------------------------------------------------------------------------------------

def test_robotiq_activation_move_and_object_detection():
    clock = VirtualClock()
    with FakeRobotiq2F85(activation_s=0.1, speed_units_s=2000.0, clock=clock) as dev:
        with RobotiqGripper(dev.port, force=77, clock=clock) as g:
            assert g.read_status()["sta"] == 3  # connect waited for activation complete ...
            assert 0.1 <= clock.now() <= 0.12  # ... polling every 10 ms of the clock
            g.command(1.0)
            assert dev.out[0] == 0x09 and dev.out[3] == 255 and dev.out[5] == 77
            clock.advance(0.1)  # 200 of the 255 units
            assert g.state().position == pytest.approx(200 / 255)
            clock.advance(0.1)
            assert g.state().position == 1.0
            dev.object_at = 128
            g.command(0.0)
            clock.advance(0.2)
            assert g.state().position == 0.0
            g.command(1.0)
            clock.advance(0.2)
            assert g.read_status()["obj"] == 2
            assert g.state().position == pytest.approx(128 / 255)
        assert dev.out[0] == 0x01  # stop on exit cleared rGTO, kept rACT
        assert dev.crc_errors == 0


def test_robotiq_garbage_on_the_line():
    clock = VirtualClock()  # activation on connect takes 50 ms of virtual time
    with FakeRobotiq2F85(clock=clock) as dev, RobotiqGripper(dev.port, retries=1, clock=clock) as g:
        dev.garbage_replies = 1
        g.state()
        dev.garbage_replies = 2
        with pytest.raises(HardwareError, match="reading the status failed: reply CRC mismatch .*garbage on the serial line"):
            g.state()


def test_robotiq_device_ignores_bad_crc_and_client_times_out():
    with FakeRobotiq2F85() as dev:
        with serial.Serial(dev.port, 115200, timeout=0.05) as s:  # waits 50 ms of wall clock: no reply comes
            bad = bytearray.fromhex("09 04 07 D0 00 03 B1 CE")
            bad[-1] ^= 1
            s.write(bytes(bad))
            assert s.read(11) == b""
            s.write(bytes.fromhex("09 04 07 D0 00 03 B1 CE"))
            reply = s.read(11)
        assert dev.crc_errors == 1 and len(reply) == 11
        assert crc16_modbus(reply[:-2]) == int.from_bytes(reply[-2:], "little")


def test_robotiq_fault_and_silence_are_reported():
    clock = VirtualClock()
    with FakeRobotiq2F85(clock=clock) as dev, RobotiqGripper(dev.port, timeout_s=0.02, clock=clock) as g:
        dev.fault = 0x0E
        with pytest.raises(HardwareError, match=r"fault 0x0E: overcurrent"):
            g.state()
        dev.fault, dev.silent = 0, True  # the client waits its read timeout (wall clock) twice, 40 ms
        with pytest.raises(HardwareError, match=r"no complete reply within 0.02 s"):
            g.state()
        dev.silent = False  # lets the stop on exit through


def test_robotiq_activation_timeout():
    clock = VirtualClock()
    with FakeRobotiq2F85(activation_s=10.0, clock=clock) as dev:
        g = RobotiqGripper(dev.port, activation_timeout_s=0.2, clock=clock)
        with pytest.raises(HardwareError, match=r"activation not complete after 0.2 s \(gSTA=1\)"):
            g.connect()
        assert 0.2 < clock.now() <= 0.22  # gave up at the first poll past the timeout, in virtual time
        g.close()


@pytest.mark.parametrize("kwargs, field", [(dict(speed=300), "speed"), (dict(force=-1), "force"), (dict(slave_id=0), "slave_id")])
def test_robotiq_bad_config(kwargs, field):
    with pytest.raises(ValueError, match=field):
        RobotiqGripper("/dev/null", **kwargs)


@pytest.mark.parametrize("kind", ["robotiq", "dynamixel"])
def test_garbage_on_the_gripper_line_mid_run_stops_the_arm(kind):
    import numpy as np

    from hardware.control_loop import ControlLoop, ControlLoopConfig
    from hardware.fakes import FakeArm
    from hardware.safety import SafetyLimits

    def close(obs):
        return np.tile(np.r_[obs["qpos"][:4], 1.0], (5, 1))

    clock = VirtualClock()
    device = (FakeRobotiq2F85 if kind == "robotiq" else FakeDynamixelServo)(clock=clock)
    client = RobotiqGripper if kind == "robotiq" else DynamixelGripper
    log = []
    with device as dev, client(dev.port, clock=clock) as gripper:
        loop = ControlLoop(FakeArm(log=log, clock=clock), close, gripper=gripper, clock=clock, limits=SafetyLimits(**FAKE_WORKSPACE),
                           config=ControlLoopConfig(inference="sync", chunk_size=5))

        def inject(step, obs, target):
            if step == 2:
                dev.garbage_replies = 10
            return False

        expected = "reply CRC mismatch .*garbage on the serial line" if kind == "robotiq" else "status packet"
        with pytest.raises(HardwareError, match=expected):
            loop.run(max_steps=10, on_step=inject)
        dev.garbage_replies = 0  # let the gripper's own stop on exit through
    events = [e for e, _ in log]
    assert events.count("servo") == 3 and events[-1] == "arm-stop"


@pytest.mark.parametrize("kind", ["robotiq", "dynamixel"])
def test_an_unplugged_adapter_is_a_hardware_error_never_a_traceback(kind):
    """The device side of the pty closes, as a USB adapter pulled out: the next exchange fails in the serial stack
    (termios' EIO, which is not an OSError) and is reported as a device fault, the run's exit 1."""
    clock = VirtualClock()
    device = (FakeRobotiq2F85 if kind == "robotiq" else FakeDynamixelServo)(clock=clock)
    client = RobotiqGripper if kind == "robotiq" else DynamixelGripper
    with device as dev:
        gripper = client(dev.port, clock=clock)
        gripper.connect()
        dev.close()
        with pytest.raises(HardwareError, match=r"the serial line failed: .*Input/output error.*; unplugged\?$"):
            gripper.state()
        gripper.close()
