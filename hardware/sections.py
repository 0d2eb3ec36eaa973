"""The device sections of a setup file (:mod:`hardware.config`): the robot, the gripper, cameras and tactile
sensors, and the arms the plausibility check knows (:data:`ARM_MODELS`). Pydantic dataclasses with
``config=STRICT``; a field the chosen ``type`` does not use is refused (it would be ignored)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass
from pydantic_core import ArgsKwargs

from controltac_il.config import STRICT
from hardware.fields import Bool, Device, Float, Int, IPAddress, Problems, Size, Str, Vec2, Vec3

ANGLE_SLACK = 1e-3  # rad: a tool angle written as 3.1416 is pi, not degrees

@dataclass(frozen=True)
class ArmModel:
    """What the plausibility check knows of an arm: its name, its reach (m, horizontally from the base axis,
    the vendor's figure) and the highest point its tool flange reaches above the base plane (m)."""

    label: str
    reach_m: float
    top_m: float


_XARM = ArmModel("an xArm 5/6/7", 0.70, 0.95)  # UFACTORY: X, Y within ±700 mm, Z up to 951.5 mm
ARM_MODELS: dict[str, ArmModel] = {  # the arms the adapters drive (xarm-python-sdk, ur-rtde)
    "xarm5": _XARM, "xarm6": _XARM, "xarm7": _XARM,
    "ur3": ArmModel("a UR3", 0.50, 0.65), "ur3e": ArmModel("a UR3e", 0.50, 0.65),
    "ur5": ArmModel("a UR5", 0.85, 1.00), "ur5e": ArmModel("a UR5e", 0.85, 1.01),
    "ur10": ArmModel("a UR10", 1.30, 1.43), "ur10e": ArmModel("a UR10e", 1.30, 1.48),
    "ur16e": ArmModel("a UR16e", 0.90, 1.08),
}
MODELS_OF = {kind: [m for m in ARM_MODELS if m.startswith(kind)] for kind in ("xarm", "ur")}


def _written(cls, data) -> set[str]:
    """The fields the input states (a YAML mapping's keys, or a constructor's arguments); empty for an instance."""
    if isinstance(data, ArgsKwargs):
        names = [f.name for f in fields(cls)]
        return set(names[:len(data.args)]) | set(data.kwargs or {})
    return set(data) if isinstance(data, dict) else set()


def _unused(problems: Problems, section, written: set[str]) -> None:
    """Fields written that the section's ``type`` does not use (they would be ignored) are problems."""
    own = section.USED[section.type]
    kind = section.type
    article = "an" if kind == "xarm" or kind[0] in "aeiou" else "a"
    what = type(section).__name__.removesuffix("Config").lower()
    for f in fields(section):
        if f.name in written and f.name != "type" and f.name not in own:
            problems.add(f.name, f"not used by {article} {kind} {what} (its fields: {', '.join(own) or 'none'})",
                         getattr(section, f.name))


@pydantic_dataclass(frozen=True, config=STRICT)
class RobotConfig:
    """type: "xarm", "ur" or "sim" (the MuJoCo scene; built by the deploy script, not here).
    ip: controller IP address (xarm, ur). tool_rpy: xArm tool (roll, pitch) at yaw 0, rad.
    tool_rotvec: UR tool orientation at yaw 0 as a rotation vector. lookahead_time, gain: UR servoL
    settings. stream_hz: rate of the interpolated xArm servo points between two control targets.
    stop_on_warning: xArm controller warnings stop the run too. model: the arm (:data:`ARM_MODELS`; required
    for a UR, default any xArm 5/6/7), whose reach bounds the workspace box."""

    type: Literal["xarm", "ur", "sim"]
    ip: IPAddress | None = None
    model: Literal[tuple(ARM_MODELS)] | None = None
    tool_rpy: Vec2 = (float(np.pi), 0.0)
    tool_rotvec: Vec3 = (float(np.pi), 0.0, 0.0)
    lookahead_time: Float = Field(0.1, ge=0.03, le=0.2)
    gain: Float = Field(300.0, ge=100, le=2000)
    stream_hz: Float = Field(100.0, ge=10, le=250)
    stop_on_warning: Bool = False

    USED: ClassVar[dict[str, tuple[str, ...]]] = {  # the fields each type reads
        "xarm": ("ip", "model", "tool_rpy", "stream_hz", "stop_on_warning"),
        "ur": ("ip", "model", "tool_rotvec", "lookahead_time", "gain"),
        "sim": (),
    }

    @model_validator(mode="wrap")
    @classmethod
    def _per_type(cls, data, handler):
        self = handler(data)
        problems = Problems("RobotConfig")
        _unused(problems, self, _written(cls, data))
        if self.type in ("xarm", "ur") and self.ip is None:
            problems.missing("ip", f"required for robot type {self.type!r} (the controller's IP address)")
        if self.type == "xarm" and self.ip is not None and ":" in self.ip:
            problems.add("ip", "the xArm SDK connects over IPv4 only: expected an address such as 192.168.1.221",
                         self.ip)
        if any(abs(a) > np.pi + ANGLE_SLACK for a in self.tool_rpy):
            problems.add("tool_rpy", "each angle must be within [-pi, pi] rad (degrees?)", list(self.tool_rpy))
        if np.linalg.norm(self.tool_rotvec) > np.pi + ANGLE_SLACK:
            problems.add("tool_rotvec", "a rotation vector's length is its angle, at most pi rad (degrees?)",
                         list(self.tool_rotvec))
        if self.type == "ur" and self.model is None:
            problems.missing("model", f"required for a UR arm (its reach bounds the workspace): one of "
                                      f"{', '.join(MODELS_OF['ur'])}")
        if self.type in MODELS_OF and self.model is not None and self.model not in MODELS_OF[self.type]:
            problems.add("model", f"not an {self.type} model: one of {', '.join(MODELS_OF[self.type])}", self.model)
        problems.raise_any()
        return self

    @property
    def arm(self) -> ArmModel | None:
        """The arm's reach figures (an xarm without ``model`` is any xArm 5/6/7: they share them); None for sim."""
        if self.type == "sim":
            return None
        return ARM_MODELS[self.model or "xarm7"]


@pydantic_dataclass(frozen=True, config=STRICT)
class GripperConfig:
    """type: "none", "xarm" (needs an xarm robot), "dynamixel" or "robotiq".
    port: serial device (dynamixel, robotiq), preferably /dev/serial/by-id/....
    baudrate: bus speed (default 57600 dynamixel, 115200 robotiq).
    dxl_id, open_position, closed_position, goal_current: Dynamixel servo ID, Goal Position ticks when
    open / closed (whole ticks, 0..4095: one turn), squeeze limit (~2.69 mA units).
    xArm gripper: open/closed in SDK units (0..850; default 850 / 0).
    slave_id, force: Robotiq Modbus address (9, 1..247) and grip force (0-255).
    speed: Robotiq 0-255 (default 255); xArm gripper 1..5000 r/min (default 5000).
    A field the chosen type does not use is an error (it would be ignored)."""

    type: Literal["none", "xarm", "dynamixel", "robotiq"] = "none"
    port: Str | None = None
    baudrate: Int | None = Field(None, gt=0)
    dxl_id: Int = Field(1, ge=0, le=252)
    open_position: Float | None = None
    closed_position: Float | None = None
    goal_current: Int = Field(300, gt=0, lt=2048)
    slave_id: Int = Field(9, ge=1, le=247)
    speed: Int | None = Field(None, ge=0)
    force: Int = Field(150, ge=0, le=255)

    USED: ClassVar[dict[str, tuple[str, ...]]] = {  # the fields each type reads
        "none": (),
        "xarm": ("open_position", "closed_position", "speed"),
        "dynamixel": ("port", "baudrate", "dxl_id", "open_position", "closed_position", "goal_current"),
        "robotiq": ("port", "baudrate", "slave_id", "speed", "force"),
    }
    DXL_TICKS: ClassVar[tuple[int, int]] = (0, 4095)  # Goal Position within one turn (X-series e.g. XM430, 0.088 deg/tick)
    XARM_POSITIONS: ClassVar[tuple[int, int]] = (0, 850)  # xArm gripper, SDK units (850 open, 0 closed)
    XARM_SPEED: ClassVar[tuple[int, int]] = (1, 5000)  # xArm gripper speed, r/min as the SDK takes it

    @model_validator(mode="wrap")
    @classmethod
    def _per_type(cls, data, handler):
        self = handler(data)
        problems = Problems("GripperConfig")
        _unused(problems, self, _written(cls, data))
        if self.type in ("dynamixel", "robotiq") and not self.port:
            problems.missing("port", f"required for a {self.type} gripper (e.g. /dev/serial/by-id/usb-...)")
        if self.type == "dynamixel":
            self._dynamixel_positions(problems)
        if self.type == "xarm":
            self._xarm_ranges(problems)
        if self.open_position is not None and self.open_position == self.closed_position:
            problems.add("closed_position", "must differ from open_position", self.closed_position)
        if self.type == "robotiq" and self.speed is not None and self.speed > 255:
            problems.add("speed", "a Robotiq speed is 0-255", self.speed)
        problems.raise_any()
        return self

    def _positions(self) -> list[tuple[str, float]]:
        """The positions given, as written (a whole number as an int)."""
        return [(n, int(v) if float(v).is_integer() else v) for n in ("open_position", "closed_position")
                if (v := getattr(self, n)) is not None]

    def _dynamixel_positions(self, problems: Problems) -> None:
        if self.open_position is None or self.closed_position is None:
            problems.missing("open_position", "open_position and closed_position (Goal Position ticks) are "
                                              "required for a dynamixel gripper")
        lo, hi = self.DXL_TICKS
        for name, v in self._positions():
            if not float(v).is_integer():
                problems.add(name, "Goal Position ticks are whole numbers", v)
            elif not lo <= v <= hi:
                problems.add(name, f"a Dynamixel Goal Position within one turn is {lo}..{hi} ticks", v)

    def _xarm_ranges(self, problems: Problems) -> None:
        lo, hi = self.XARM_POSITIONS
        for name, v in self._positions():
            if not lo <= v <= hi:
                problems.add(name, f"an xArm gripper position is {lo}..{hi} (SDK units)", v)
        if self.speed is not None and not self.XARM_SPEED[0] <= self.speed <= self.XARM_SPEED[1]:
            problems.add("speed", f"an xArm gripper speed is {self.XARM_SPEED[0]}..{self.XARM_SPEED[1]} (r/min)",
                         self.speed)


@pydantic_dataclass(frozen=True, config=STRICT)
class CameraConfig:
    """device: /dev/videoN, an index, a name fragment under /dev/v4l/by-id, or a video file.
    size: output [H, W]. fps: requested rate. crop_fraction: border removed from each side.
    max_age_s: the newest frame may be this old before the camera counts as stalled (None: loop watchdog only)."""

    device: Device
    size: Size = (240, 320)
    fps: Float | None = Field(30.0, gt=0, le=240)
    crop_fraction: Float = Field(0.0, ge=0, lt=0.5)
    max_age_s: Float | None = Field(None, gt=0)


@pydantic_dataclass(frozen=True, config=STRICT)
class TactileConfig(CameraConfig):
    """A GelSight Mini: as a camera, with the 15 % crop, 25 fps and a background over ``background_frames``
    no-contact frames at start (default device: the only "GelSight Mini" under /dev/v4l/by-id)."""

    device: Device = "GelSight Mini"
    fps: Float | None = Field(25.0, gt=0, le=240)
    crop_fraction: Float = Field(0.15, ge=0, lt=0.5)
    background_frames: Int = Field(30, ge=1)
