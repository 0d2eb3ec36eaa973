"""Serial devices emulated on a pseudo-terminal, so the real client stack (pyserial, dynamixel_sdk)
does the talking in tests and benchmarks.

``FakeDynamixelServo``: a DYNAMIXEL X-series servo speaking Protocol 2.0 (PING, READ, WRITE, REBOOT;
byte stuffing; CRC-16 polynomial 0x8005 checked on every instruction, a bad one answered with the
CRC error status). ``FakeRobotiq2F85``: a Robotiq 2F-85 on Modbus RTU (function codes 16 and 4, slave
9, CRC-16/MODBUS checked on every request). Both move their fingers at a fixed speed, can block on
an object, and take injected faults: garbage bytes instead of a reply, silence, device fault codes.
Use as a context manager; ``port`` is the path a client opens. The mechanics (finger motion, activation
time) follow the injected ``clock`` (wall clock by default): with a
:class:`~hardware.interfaces.VirtualClock`, a test moves the fingers by advancing it, without sleeping.
"""

from __future__ import annotations

import os
import select
import threading
import tty

import numpy as np

from hardware.interfaces import Clock, WallClock
from hardware.robotiq import crc16_modbus


class PtyDevice:
    """A pseudo-terminal pair with a thread answering whatever the client writes to ``port``."""

    def __init__(self, clock: Clock | None = None):
        self.clock = clock or WallClock()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo / line editing before the client configures the port
        self.port = os.ttyname(self._slave)
        self._buf = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name=f"fake-{type(self).__name__}", daemon=True)
        self.garbage_replies = 0  # next N requests are answered with noise
        self.silent = False  # stop answering (device unplugged / powered off)
        self.requests = 0
        self.crc_errors = 0

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def _serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.02)
            self._tick()
            if not ready:
                continue
            try:
                self._buf += os.read(self._master, 4096)
            except OSError:
                return
            while True:
                reply = self._take_request()
                if reply is None:
                    break
                self.requests += 1
                if self.silent:
                    continue
                if self.garbage_replies > 0:
                    self.garbage_replies -= 1
                    reply = bytes(np.random.default_rng(self.requests).integers(0, 256, len(reply), dtype=np.uint8))
                if reply:
                    os.write(self._master, reply)

    def _tick(self) -> None:
        """Advance the emulated mechanics to ``clock.now()`` (called about every 20 ms and on each request)."""

    def _take_request(self) -> bytes | None:
        """Parse one request from ``self._buf``: the reply bytes (b"" for none), or None if incomplete."""
        raise NotImplementedError


# -- DYNAMIXEL Protocol 2.0 ------------------------------------------------------------------------

def dxl_crc(data: bytes) -> int:
    """CRC-16 of DYNAMIXEL Protocol 2.0: polynomial 0x8005, initial 0, not reflected."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


_DXL_HEADER = b"\xff\xff\xfd\x00"


def _unstuff(body: bytes) -> bytes:
    return body.replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


def _stuff(body: bytes) -> bytes:
    return body.replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")


class FakeDynamixelServo(PtyDevice):
    """One X-series servo (control table addresses of the XM430 e-manual) on a pty.

    speed_ticks_s: how fast Present Position follows Goal Position while torque is on.
    object_at: a position (ticks) the fingers cannot pass (an object in the gripper), or None.
    """

    MODEL_XM430_W350 = 1020

    def __init__(self, dxl_id: int = 1, speed_ticks_s: float = 20000.0, start_position: int = 0,
                 clock: Clock | None = None):
        super().__init__(clock)
        self.dxl_id = dxl_id
        self.table = bytearray(256)
        self.table[0:2] = self.MODEL_XM430_W350.to_bytes(2, "little")
        self.table[7] = dxl_id
        self.table[11] = 3  # Operating Mode: position control (factory default)
        self.table[38:40] = (1193).to_bytes(2, "little")  # Current Limit
        self._set_i32(132, start_position)
        self._set_i32(116, start_position)
        self.speed_ticks_s = speed_ticks_s
        self.object_at: int | None = None
        self.hardware_error = 0
        self._last_tick = self.clock.now()
        self.writes: list[tuple[int, bytes]] = []

    def _get_i32(self, addr: int) -> int:
        return int.from_bytes(self.table[addr:addr + 4], "little", signed=True)

    def _set_i32(self, addr: int, v: int) -> None:
        self.table[addr:addr + 4] = int(v).to_bytes(4, "little", signed=True)

    def _tick(self) -> None:
        now = self.clock.now()
        dt, self._last_tick = now - self._last_tick, now
        if self.table[64] != 1:  # torque off: fingers stay
            return
        pos, goal = self._get_i32(132), self._get_i32(116)
        step = int(np.clip(goal - pos, -self.speed_ticks_s * dt, self.speed_ticks_s * dt))
        new = pos + step
        if self.object_at is not None and (pos <= self.object_at < new or new < self.object_at <= pos):
            new = self.object_at  # the fingers meet the object
        self._set_i32(132, new)
        squeezing = self.object_at is not None and new == self.object_at and goal != new
        current = int.from_bytes(self.table[102:104], "little", signed=True) if squeezing else 0
        self.table[126:128] = current.to_bytes(2, "little", signed=True)

    def _status(self, error: int, params: bytes = b"") -> bytes:
        payload = _stuff(b"\x55" + bytes([error]) + params)
        packet = _DXL_HEADER + bytes([self.dxl_id]) + (len(payload) + 2).to_bytes(2, "little") + payload
        return packet + dxl_crc(packet).to_bytes(2, "little")

    def _take_request(self) -> bytes | None:
        buf = self._buf
        start = buf.find(_DXL_HEADER)
        if start < 0:
            del buf[: max(0, len(buf) - 3)]  # noise: keep a possible partial header
            return None
        del buf[:start]
        if len(buf) < 7:
            return None
        length = int.from_bytes(buf[5:7], "little")
        if len(buf) < 7 + length:
            return None
        packet = bytes(buf[: 7 + length])
        del buf[: 7 + length]
        dxl_id = packet[4]
        if dxl_id not in (self.dxl_id, 0xFE):
            return b""
        if dxl_crc(packet[:-2]) != int.from_bytes(packet[-2:], "little"):
            self.crc_errors += 1
            return self._status(0x03)  # CRC error
        self._tick()
        inst, params = packet[7], _unstuff(packet[8:-2])
        alert = 0x80 if self.hardware_error else 0
        if inst == 0x01:  # PING: model number, firmware version
            return self._status(alert, bytes(self.table[0:2]) + b"\x2d")
        if inst == 0x02:  # READ addr(2) len(2)
            addr, n = int.from_bytes(params[0:2], "little"), int.from_bytes(params[2:4], "little")
            self.table[70] = self.hardware_error
            return self._status(alert, bytes(self.table[addr:addr + n]))
        if inst == 0x03:  # WRITE addr(2) data
            addr, data = int.from_bytes(params[0:2], "little"), params[2:]
            if addr == 11 and self.table[64] == 1:
                return self._status(alert | 0x07)  # Access error: EEPROM area while torque is on
            self.table[addr:addr + len(data)] = data
            self.writes.append((addr, bytes(data)))
            return self._status(alert)
        if inst == 0x08:  # REBOOT clears the hardware error
            self.hardware_error = 0
            self.table[64] = 0
            return self._status(0)
        return self._status(alert | 0x02)  # instruction error


# -- Robotiq 2F-85, Modbus RTU -------------------------------------------------------------------

class FakeRobotiq2F85(PtyDevice):
    """Robotiq 2F-85 register map on Modbus RTU: output registers 0x03E8.. (FC16), input 0x07D0.. (FC04).

    activation_s: time from rACT=1 to "activation complete" (gSTA = 3).
    speed_units_s: position units (0 open .. 255 closed) travelled per second.
    object_at: position where the fingers meet an object (gOBJ = 2), or None.
    """

    def __init__(self, slave_id: int = 9, activation_s: float = 0.05, speed_units_s: float = 2000.0,
                 clock: Clock | None = None):
        super().__init__(clock)
        self.slave_id, self.activation_s, self.speed_units_s = slave_id, activation_s, speed_units_s
        self.out = bytearray(6)  # ACTION REQUEST, reserved, reserved, POSITION REQUEST, SPEED, FORCE
        self.position = 0.0
        self.fault = 0
        self.object_at: float | None = None
        self._activated_at: float | None = None
        self._last_tick = self.clock.now()

    def _frame(self, payload: bytes) -> bytes:
        return payload + crc16_modbus(payload).to_bytes(2, "little")

    def _tick(self) -> None:
        now = self.clock.now()
        dt, self._last_tick = now - self._last_tick, now
        if self._activated_at is None or now - self._activated_at < self.activation_s or not self.out[0] & 0x08:
            return
        goal = float(self.out[3])
        step = float(np.clip(goal - self.position, -self.speed_units_s * dt, self.speed_units_s * dt))
        new = self.position + step
        if self.object_at is not None and self.position <= self.object_at < new:
            new = self.object_at
        self.position = new

    def status_bytes(self) -> bytes:
        now = self.clock.now()
        act = self.out[0] & 0x01
        gsta = 0
        if act and self._activated_at is not None:
            gsta = 3 if now - self._activated_at >= self.activation_s else 1
        goal = self.out[3]
        gobj = 3 if round(self.position) == goal else 0
        if self.object_at is not None and abs(self.position - self.object_at) < 0.5 and goal > self.object_at:
            gobj = 2
        status = act | (self.out[0] & 0x08) | (gsta << 4) | (gobj << 6)
        return bytes([status, 0, self.fault, goal, int(round(self.position)), 0])

    def _take_request(self) -> bytes | None:
        buf = self._buf
        while buf and buf[0] != self.slave_id:
            del buf[0]  # resynchronise on the slave address
        if len(buf) < 8:
            return None
        fc = buf[1]
        if fc == 0x10:
            if len(buf) < 7 or len(buf) < 9 + buf[6]:
                return None
            n = 9 + buf[6]
        elif fc == 0x04:
            n = 8
        else:
            n = 8  # unknown function: consume a minimal frame and answer "illegal function"
        frame = bytes(buf[:n])
        del buf[:n]
        if crc16_modbus(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
            self.crc_errors += 1
            return b""  # Modbus RTU: a frame with a bad CRC is ignored (the client times out)
        self._tick()
        addr, count = int.from_bytes(frame[2:4], "big"), int.from_bytes(frame[4:6], "big")
        if fc == 0x10:
            if addr != 0x03E8 or count != 3:
                return self._frame(bytes([self.slave_id, 0x90, 0x02]))  # illegal data address
            self.out[:] = frame[7:13]
            if self.out[0] & 0x01 and self._activated_at is None:
                self._activated_at = self.clock.now()
            elif not self.out[0] & 0x01:
                self._activated_at = None
            return self._frame(frame[:6])
        if fc == 0x04:
            if addr != 0x07D0 or not 1 <= count <= 3:
                return self._frame(bytes([self.slave_id, 0x84, 0x02]))
            data = self.status_bytes()[: 2 * count]
            return self._frame(bytes([self.slave_id, 0x04, len(data)]) + data)
        return self._frame(bytes([self.slave_id, fc | 0x80, 0x01]))
