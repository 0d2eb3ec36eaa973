"""Robotiq 2F-85 gripper over RS-485 Modbus RTU (pyserial), register map of the 2F-85 manual.

Output registers from 0x03E8 (written with function code 16): ACTION REQUEST (rACT bit 0, rGTO bit 3),
two reserved bytes, POSITION REQUEST (0 open .. 255 closed), SPEED, FORCE. Input registers from 0x07D0
(read with function code 4): GRIPPER STATUS (gACT bit 0, gGTO bit 3, gSTA bits 4-5, gOBJ bits 6-7),
reserved, FAULT STATUS, POSITION REQUEST ECHO, POSITION, CURRENT. Frames end with CRC-16/MODBUS,
low byte first; every reply's CRC is checked.
"""

from __future__ import annotations

from controltac_il.config import one_line
from controltac_il.extras import require
from hardware.interfaces import SERIAL_ERRORS, Clock, Gripper, GripperState, HardwareError, WallClock

serial = require("serial", "robotiq", "the Robotiq gripper")

FAULTS = {
    0x05: "action delayed: activation must complete first",
    0x07: "activation bit must be set before the action",
    0x08: "maximum operating temperature exceeded",
    0x09: "no communication for at least 1 s",
    0x0A: "under minimum operating voltage",
    0x0B: "automatic release in progress",
    0x0C: "internal fault",
    0x0D: "activation fault",
    0x0E: "overcurrent triggered",
    0x0F: "automatic release completed",
}


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS: reflected polynomial 0xA001, initial 0xFFFF (sent low byte first)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


class RobotiqGripper(Gripper):
    """Robotiq 2F-85 on a serial port (RS-485 adapter), Modbus RTU at 115200 8N1.

    port: serial device, e.g. /dev/ttyUSB0 (prefer /dev/serial/by-id/...). slave_id: Modbus address (9).
    speed / force: 0..255 for every move. timeout_s: wait for one reply. retries: extra attempts after a
    corrupt or missing reply. activation_timeout_s: wait for "activation complete" on connect (clock
    seconds; the status is polled every 10 ms of ``clock``). clock: time of the stamps and that wait.
    """

    def __init__(self, port: str, slave_id: int = 9, baudrate: int = 115200, speed: int = 255, force: int = 150,
                 timeout_s: float = 0.1, retries: int = 1, activation_timeout_s: float = 5.0,
                 clock: Clock | None = None):
        for name, v in (("speed", speed), ("force", force)):
            if not (isinstance(v, int) and 0 <= v <= 255):
                raise ValueError(f"{name} must be an integer in 0..255, got {v!r}")
        if not (isinstance(slave_id, int) and 1 <= slave_id <= 247):
            raise ValueError(f"slave_id must be a Modbus address in 1..247, got {slave_id!r}")
        self.port, self.slave_id, self.baudrate = port, slave_id, baudrate
        self.speed, self.force, self.timeout_s, self.retries = speed, force, timeout_s, retries
        self.activation_timeout_s = activation_timeout_s
        self.clock = clock or WallClock()
        self._ser: serial.Serial | None = None
        self._last_request = 0

    # -- Modbus RTU ------------------------------------------------------------------------------
    def _transact(self, pdu: bytes, what: str) -> bytes:
        if self._ser is None:
            raise HardwareError(f"robotiq on {self.port}: not connected (call connect())")
        frame = bytes([self.slave_id]) + pdu
        frame += crc16_modbus(frame).to_bytes(2, "little")
        try:
            return self._exchange(frame, pdu, what)
        except SERIAL_ERRORS as exc:  # a fault of the run (exit 1), never a traceback or a usage error
            raise HardwareError(f"robotiq on {self.port}: {what}: the serial line failed: {one_line(exc)}; "
                                "unplugged?") from None

    def _exchange(self, frame: bytes, pdu: bytes, what: str) -> bytes:
        """One request with retries: the reply, checked; HardwareError naming what failed."""
        problems = []
        for _ in range(1 + self.retries):
            self._ser.reset_input_buffer()
            self._ser.write(frame)
            reply = self._ser.read(5)
            if len(reply) == 5 and reply[0] == self.slave_id and reply[1] == pdu[0] | 0x80:
                if crc16_modbus(reply[:3]) == int.from_bytes(reply[3:5], "little"):
                    raise HardwareError(f"robotiq on {self.port}: {what} refused with Modbus exception code {reply[2]}")
            expected = 8 if pdu[0] == 0x10 else 5 + 2 * int.from_bytes(pdu[3:5], "big")
            if len(reply) == 5:
                reply += self._ser.read(expected - 5)
            if len(reply) < expected:
                problems.append(f"no complete reply within {self.timeout_s} s ({len(reply)} of {expected} bytes)")
                continue
            if crc16_modbus(reply[:-2]) != int.from_bytes(reply[-2:], "little"):
                problems.append(f"reply CRC mismatch ({reply.hex(' ')}): garbage on the serial line?")
                continue
            if reply[0] != self.slave_id or reply[1] != pdu[0]:
                problems.append(f"reply from slave {reply[0]} function {reply[1]}, expected {self.slave_id} / {pdu[0]}")
                continue
            return reply
        raise HardwareError(f"robotiq on {self.port}: {what} failed: " + "; ".join(problems))

    def _write_request(self, action: int, position: int) -> None:
        data = bytes([action, 0, 0, position, self.speed, self.force])
        self._transact(b"\x10\x03\xe8\x00\x03\x06" + data, "writing the action request")
        self._last_request = position

    def read_status(self) -> dict:
        """Decoded status registers: act, gto, sta, obj, fault, position_request, position, current (raw units)."""
        r = self._transact(b"\x04\x07\xd0\x00\x03", "reading the status")[3:9]
        return {"act": r[0] & 1, "gto": (r[0] >> 3) & 1, "sta": (r[0] >> 4) & 3, "obj": (r[0] >> 6) & 3,
                "fault": r[2], "position_request": r[3], "position": r[4], "current": r[5]}

    def _raise_fault(self, st: dict) -> None:
        code = st["fault"] & 0x0F
        if code >= 0x08 or (code in (0x05, 0x07) and st["sta"] == 3):
            raise HardwareError(f"robotiq on {self.port}: fault 0x{code:02X}: {FAULTS.get(code, 'unknown fault')}")

    # -- Gripper ---------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, reset and activate the gripper, wait for activation complete (gSTA = 3)."""
        try:
            self._ser = serial.Serial(self.port, self.baudrate, bytesize=8, parity="N", stopbits=1, timeout=self.timeout_s)
        except (serial.SerialException, OSError) as exc:  # unplugged adapter, wrong path, no permission
            raise HardwareError(f"robotiq on {self.port}: cannot open the port ({one_line(exc)}); check "
                                "the USB adapter and gripper.port (ls /dev/serial/by-id)") from None
        self._write_request(0x00, 0)  # clear rACT
        self._write_request(0x01, 0)  # activate
        deadline = self.clock.now() + self.activation_timeout_s
        while True:
            st = self.read_status()
            self._raise_fault(st)
            if st["sta"] == 3:
                return
            if self.clock.now() > deadline:
                raise HardwareError(
                    f"robotiq on {self.port}: activation not complete after {self.activation_timeout_s} s (gSTA={st['sta']})"
                )
            self.clock.sleep_until(self.clock.now() + 0.01)

    def command(self, closing: float) -> None:
        if not 0.0 <= closing <= 1.0:
            raise ValueError(f"gripper command must be in [0, 1] (0 open, 1 closed), got {closing}")
        self._write_request(0x09, int(round(255 * closing)))  # rACT + rGTO

    def state(self) -> GripperState:
        st = self.read_status()
        self._raise_fault(st)
        return GripperState(st["position"] / 255.0, self.clock.now())

    def stop(self) -> None:
        """Clear rGTO: the fingers stop where they are (an object already gripped stays gripped)."""
        if self._ser is not None:
            self._write_request(0x01, self._last_request)

    def close(self) -> None:
        if self._ser is not None:
            self._ser.close()
            self._ser = None
