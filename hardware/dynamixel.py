"""Gripper driven by one DYNAMIXEL X-series servo (dynamixel-sdk, Protocol 2.0) in
current-based position control, so the fingers close to a position but squeeze with at most
``goal_current``. Control table addresses from the X-series (XM430) e-manual.
"""

from __future__ import annotations

from controltac_il.config import one_line
from controltac_il.extras import require
from hardware.interfaces import SERIAL_ERRORS, Clock, Gripper, GripperState, HardwareError, WallClock

ADDR_OPERATING_MODE = 11  # 1 byte, EEPROM (write with torque off)
ADDR_TORQUE_ENABLE = 64  # 1 byte
ADDR_HARDWARE_ERROR = 70  # 1 byte
ADDR_GOAL_CURRENT = 102  # 2 bytes, unit ~2.69 mA
ADDR_PROFILE_VELOCITY = 112  # 4 bytes, unit 0.229 rev/min, 0 = as fast as possible
ADDR_GOAL_POSITION = 116  # 4 bytes, unit 0.088 deg
ADDR_PRESENT_CURRENT = 126  # 2 bytes
ADDR_PRESENT_POSITION = 132  # 4 bytes
MODE_CURRENT_BASED_POSITION = 5

dxl = require("dynamixel_sdk", "dynamixel", "the Dynamixel gripper")

HARDWARE_ERRORS = {0: "input voltage", 2: "overheating", 3: "motor encoder", 4: "electrical shock", 5: "overload"}


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


class DynamixelGripper(Gripper):
    """A one-servo parallel gripper.

    port: serial device of the U2D2 / USB adapter (prefer /dev/serial/by-id/...). dxl_id: servo ID.
    baudrate: bus speed (57600 is the X-series default). open_position / closed_position: Goal Position
    ticks of the open and closed fingers (either order). goal_current: squeeze limit in the servo's
    current unit (about 2.69 mA; must not exceed its Current Limit). profile_velocity: 0 = fastest.
    retries: extra attempts after a failed exchange (garbage or no reply) before raising.
    """

    def __init__(self, port: str, dxl_id: int = 1, baudrate: int = 57600, open_position: int = 0,
                 closed_position: int = 1000, goal_current: int = 300, profile_velocity: int = 0,
                 retries: int = 1, clock: Clock | None = None):
        if not (isinstance(dxl_id, int) and 0 <= dxl_id <= 252):
            raise ValueError(f"dxl_id must be an integer in 0..252, got {dxl_id!r}")
        if open_position == closed_position:
            raise ValueError("open_position and closed_position must differ (Goal Position ticks)")
        if not (isinstance(goal_current, int) and 0 < goal_current < 2048):
            raise ValueError(f"goal_current must be a positive integer (units of ~2.69 mA), got {goal_current!r}")
        self.port, self.dxl_id, self.baudrate = port, dxl_id, baudrate
        self.open_position, self.closed_position = int(open_position), int(closed_position)
        self.goal_current, self.profile_velocity, self.retries = goal_current, profile_velocity, retries
        self.clock = clock or WallClock()
        self._port: dxl.PortHandler | None = None
        self._packet = dxl.PacketHandler(2.0)
        self.model_number: int | None = None

    def _where(self) -> str:
        return f"dynamixel id {self.dxl_id} on {self.port}"

    def _call(self, what: str, fn, *args):
        """Run one SDK exchange with retries; raise HardwareError naming the register on failure."""
        if self._port is None:
            raise HardwareError(f"{self._where()}: not connected (call connect())")
        problems = []
        for _ in range(1 + self.retries):
            try:
                out = fn(self._port, self.dxl_id, *args)
            except SERIAL_ERRORS as exc:  # a fault of the run (exit 1), never a traceback or a usage error
                raise HardwareError(f"{self._where()}: {what}: the serial line failed: {one_line(exc)}; "
                                    "unplugged?") from None
            value, result, error = (None, *out) if len(out) == 2 else out
            if result != dxl.COMM_SUCCESS:
                problems.append(self._packet.getTxRxResult(result))
                continue
            if error & 0x80:
                self._raise_hardware_error(what)
            if error & 0x7F:
                raise HardwareError(f"{self._where()}: {what}: {self._packet.getRxPacketError(error)}")
            return value
        raise HardwareError(f"{self._where()}: {what} failed: " + "; ".join(problems))

    def _raise_hardware_error(self, what: str) -> None:
        status, result, _ = self._packet.read1ByteTxRx(self._port, self.dxl_id, ADDR_HARDWARE_ERROR)
        names = [n for bit, n in HARDWARE_ERRORS.items() if status >> bit & 1] if result == dxl.COMM_SUCCESS else []
        raise HardwareError(
            f"{self._where()}: {what}: hardware error status 0x{status:02X} ({', '.join(names) or 'unknown'}); "
            "the servo needs a reboot"
        )

    def connect(self) -> None:
        """Open the port, ping the servo, set current-based position mode, goal current and torque on."""
        self._port = dxl.PortHandler(self.port)
        try:
            if not self._port.setBaudRate(self.baudrate):
                raise HardwareError(f"{self._where()}: cannot open at {self.baudrate} baud")
        except OSError as exc:
            self._port = None
            raise HardwareError(f"{self._where()}: cannot open the port: {exc}") from exc
        self.model_number = self._call("ping", self._packet.ping)
        self._call("torque off", self._packet.write1ByteTxRx, ADDR_TORQUE_ENABLE, 0)
        self._call("operating mode", self._packet.write1ByteTxRx, ADDR_OPERATING_MODE, MODE_CURRENT_BASED_POSITION)
        self._call("goal current", self._packet.write2ByteTxRx, ADDR_GOAL_CURRENT, self.goal_current)
        self._call("profile velocity", self._packet.write4ByteTxRx, ADDR_PROFILE_VELOCITY, self.profile_velocity)
        self._call("torque on", self._packet.write1ByteTxRx, ADDR_TORQUE_ENABLE, 1)

    def _ticks(self, closing: float) -> int:
        return int(round(self.open_position + closing * (self.closed_position - self.open_position)))

    def command(self, closing: float) -> None:
        if not 0.0 <= closing <= 1.0:
            raise ValueError(f"gripper command must be in [0, 1] (0 open, 1 closed), got {closing}")
        self._call("goal position", self._packet.write4ByteTxRx, ADDR_GOAL_POSITION, self._ticks(closing) & 0xFFFFFFFF)

    def state(self) -> GripperState:
        ticks = _signed(self._call("present position", self._packet.read4ByteTxRx, ADDR_PRESENT_POSITION), 32)
        frac = (ticks - self.open_position) / (self.closed_position - self.open_position)
        return GripperState(min(1.0, max(0.0, frac)), self.clock.now())

    def present_current(self) -> int:
        """Present Current (signed, ~2.69 mA units): the squeeze on a gripped object."""
        return _signed(self._call("present current", self._packet.read2ByteTxRx, ADDR_PRESENT_CURRENT), 16)

    def stop(self) -> None:
        """Nothing to send: the servo holds its last goal with at most ``goal_current`` (a gripped object stays)."""

    def close(self) -> None:
        """Close the port; torque stays on so a held object is not dropped."""
        if self._port is not None:
            self._port.closePort()
            self._port = None
