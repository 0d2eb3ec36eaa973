"""One YAML file per robot setup: robot, gripper, cameras, tactile sensors, safety limits, loop timing.

``load_setup(path)`` reads and validates it; every error names the file and the field
(``setup.yaml: gripper.port: required for a dynamixel gripper``). ``open_setup(cfg)`` connects the
devices it describes and closes them again (arm stopped first). Example files: ``hardware/configs/``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from hardware.control_loop import ControlLoopConfig
from hardware.interfaces import Arm, FrameSource, Gripper
from hardware.safety import SafetyLimits


class ConfigError(ValueError):
    """A setup file is malformed; the message names the file and the field."""


@dataclass
class RobotConfig:
    """type: "xarm", "ur" or "sim" (the MuJoCo scene; built by the deploy script, not here).
    ip: controller address (xarm, ur). tool_rpy: xArm tool (roll, pitch) at yaw 0, rad.
    tool_rotvec: UR tool orientation at yaw 0 as a rotation vector. lookahead_time, gain: UR servoL
    settings. stream_hz: rate of the interpolated xArm servo points between two control targets.
    stop_on_warning: xArm controller warnings stop the run too."""

    type: str
    ip: str | None = None
    tool_rpy: list[float] = field(default_factory=lambda: [float(np.pi), 0.0])
    tool_rotvec: list[float] = field(default_factory=lambda: [float(np.pi), 0.0, 0.0])
    lookahead_time: float = 0.1
    gain: float = 300.0
    stream_hz: float = 100.0
    stop_on_warning: bool = False

    def __post_init__(self):
        if self.type not in ("xarm", "ur", "sim"):
            raise ValueError(f"type: expected 'xarm', 'ur' or 'sim', got {self.type!r}")
        if self.type in ("xarm", "ur") and not self.ip:
            raise ValueError(f"ip: required for robot type {self.type!r} (the controller's address)")
        if len(self.tool_rpy) != 2:
            raise ValueError(f"tool_rpy: expected [roll, pitch] in radians, got {self.tool_rpy!r}")
        if len(self.tool_rotvec) != 3:
            raise ValueError(f"tool_rotvec: expected [rx, ry, rz] (rotation vector, rad), got {self.tool_rotvec!r}")
        if not 0.03 <= self.lookahead_time <= 0.2:
            raise ValueError(f"lookahead_time: expected 0.03 to 0.2 s, got {self.lookahead_time}")
        if not 100 <= self.gain <= 2000:
            raise ValueError(f"gain: expected 100 to 2000, got {self.gain}")
        if not 10 <= self.stream_hz <= 250:
            raise ValueError(f"stream_hz: expected 10 to 250 Hz, got {self.stream_hz}")


@dataclass
class GripperConfig:
    """type: "none", "xarm" (needs an xarm robot), "dynamixel" or "robotiq".
    port: serial device (dynamixel, robotiq), preferably /dev/serial/by-id/....
    baudrate: bus speed (default 57600 dynamixel, 115200 robotiq).
    dxl_id, open_position, closed_position, goal_current: Dynamixel servo ID, Goal Position ticks when
    open / closed, squeeze limit (~2.69 mA units). xArm gripper: open/closed in SDK units (850 / 0).
    slave_id, force: Robotiq Modbus address (9) and grip force (0-255).
    speed: Robotiq 0-255 (default 255); xArm gripper pulse/s (default 5000)."""

    type: str = "none"
    port: str | None = None
    baudrate: int | None = None
    dxl_id: int = 1
    open_position: float | None = None
    closed_position: float | None = None
    goal_current: int = 300
    slave_id: int = 9
    speed: int | None = None
    force: int = 150

    def __post_init__(self):
        if self.type not in ("none", "xarm", "dynamixel", "robotiq"):
            raise ValueError(f"type: expected 'none', 'xarm', 'dynamixel' or 'robotiq', got {self.type!r}")
        if self.type in ("dynamixel", "robotiq") and not self.port:
            raise ValueError(f"port: required for a {self.type} gripper (e.g. /dev/serial/by-id/usb-...)")
        if self.type == "dynamixel" and (self.open_position is None or self.closed_position is None):
            raise ValueError("open_position: open_position and closed_position (Goal Position ticks) are required "
                             "for a dynamixel gripper")


@dataclass
class CameraConfig:
    """device: /dev/videoN, an index, a name fragment under /dev/v4l/by-id, or a video file.
    size: output [H, W]. fps: requested rate. crop_fraction: border removed from each side.
    max_age_s: the newest frame may be this old before the camera counts as stalled (None: loop watchdog only)."""

    device: str | int
    size: list[int] = field(default_factory=lambda: [240, 320])
    fps: float | None = 30.0
    crop_fraction: float = 0.0
    max_age_s: float | None = None

    def __post_init__(self):
        if len(self.size) != 2 or min(self.size) < 1:
            raise ValueError(f"size: expected [H, W] with positive integers, got {self.size!r}")
        if not 0.0 <= self.crop_fraction < 0.5:
            raise ValueError(f"crop_fraction: expected a number in [0, 0.5), got {self.crop_fraction!r}")


@dataclass
class TactileConfig(CameraConfig):
    """A GelSight Mini: as a camera, with the 15 % crop, 25 fps and a background over ``background_frames``
    no-contact frames at start (default device: the only "GelSight Mini" under /dev/v4l/by-id)."""

    device: str | int = "GelSight Mini"
    fps: float | None = 25.0
    crop_fraction: float = 0.15
    background_frames: int = 30

    def __post_init__(self):
        super().__post_init__()
        if self.background_frames < 1:
            raise ValueError(f"background_frames: expected an integer >= 1, got {self.background_frames!r}")


@dataclass
class SetupConfig:
    """A whole setup. name: free text. robot / gripper: see their classes. cameras / tactile: name ->
    device (observation keys images/<name>, tactile/<name>). limits: SafetyLimits fields.
    control: ControlLoopConfig fields (rate_hz, inference, inference_deadline_s, ...)."""

    robot: RobotConfig
    name: str = "setup"
    gripper: GripperConfig = field(default_factory=GripperConfig)
    cameras: dict[str, CameraConfig] = field(default_factory=dict)
    tactile: dict[str, TactileConfig] = field(default_factory=dict)
    limits: SafetyLimits = field(default_factory=SafetyLimits)
    control: ControlLoopConfig = field(default_factory=ControlLoopConfig)

    def __post_init__(self):
        if self.gripper.type == "xarm" and self.robot.type != "xarm":
            raise ValueError("gripper.type: an xarm gripper needs robot.type xarm")


# -- parsing with field paths in the errors ----------------------------------------------------------

def _is_optional(tp) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp)


def _convert(value, tp, path: str):
    """Check ``value`` against the annotation ``tp``; return it converted (lists of numbers, nested dataclasses)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if value is None:
        if _is_optional(tp):
            return None
        raise ConfigError(f"{path}: a value is required")
    if origin in (typing.Union, types.UnionType):
        expected = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _convert(value, arg, path)
            except ConfigError as exc:
                expected.append(str(exc).split(": ", 1)[-1].split(", got")[0].removeprefix("expected "))
        raise ConfigError(f"{path}: expected {' or '.join(expected)}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, path)
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: expected a mapping of name -> settings, got {type(value).__name__}")
        return {str(k): _convert(v, args[1], f"{path}.{k}") for k, v in value.items()}
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        return [_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value)]
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {value!r}")
        return value
    return value


def _build(cls, data, path: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(map(str, data)) - set(fields))
    if unknown:
        raise ConfigError(f"{path}.{unknown[0]}: unknown field; expected one of {', '.join(sorted(fields))}")
    kwargs = {}
    for name, f in fields.items():
        sub = f"{path}.{name}" if path else name
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], sub)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{sub}: required field is missing")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as exc:
        msg = str(exc)
        first = msg.split(":", 1)[0].split()[0] if msg else ""
        if first.split(".")[0] in fields:  # the message starts with the field name
            raise ConfigError(f"{path + '.' if path else ''}{msg}") from None
        raise ConfigError(f"{path or 'setup'}: {msg}") from None


def parse_setup(data: dict, source: str = "setup") -> SetupConfig:
    """Validate a parsed YAML mapping; errors read ``<source>: <field path>: <problem>``."""
    try:
        return _build(SetupConfig, data, "")
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def load_setup(path: str | Path) -> SetupConfig:
    """Read and validate a setup YAML file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the setup file: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    return parse_setup(data if data is not None else {}, str(path))


# -- building devices ------------------------------------------------------------------------------

def build_arm(cfg: SetupConfig) -> Arm:
    """The arm adapter described by ``cfg.robot`` (not connected)."""
    r = cfg.robot
    if r.type == "xarm":
        from hardware.xarm import XArm

        return XArm(r.ip, tool_rpy=tuple(r.tool_rpy), period_s=cfg.control.period_s,
                    stream_hz=max(r.stream_hz, cfg.control.rate_hz), stop_on_warning=r.stop_on_warning)
    if r.type == "ur":
        from hardware.ur import URArm

        return URArm(r.ip, tool_rotvec=r.tool_rotvec, period_s=cfg.control.period_s,
                     lookahead_time=r.lookahead_time, gain=r.gain)
    raise ConfigError("robot.type: 'sim' is the MuJoCo scene; it is built by the deploy script (--robot sim)")


def build_gripper(cfg: SetupConfig, arm: Arm) -> Gripper | None:
    """The gripper adapter described by ``cfg.gripper`` (not connected), or None."""
    g = cfg.gripper
    if g.type == "none":
        return None
    if g.type == "xarm":
        from hardware.xarm import XArmGripper

        extra = {k: v for k, v in (("open_position", g.open_position), ("closed_position", g.closed_position)) if v is not None}
        return XArmGripper(arm, speed=float(g.speed or 5000), **extra)
    if g.type == "dynamixel":
        from hardware.dynamixel import DynamixelGripper

        return DynamixelGripper(g.port, dxl_id=g.dxl_id, baudrate=g.baudrate or 57600,
                                open_position=int(g.open_position), closed_position=int(g.closed_position),
                                goal_current=g.goal_current)
    from hardware.robotiq import RobotiqGripper

    return RobotiqGripper(g.port, slave_id=g.slave_id, baudrate=g.baudrate or 115200,
                          speed=255 if g.speed is None else g.speed, force=g.force)


def build_frame_sources(cfg: SetupConfig) -> tuple[dict[str, FrameSource], dict[str, FrameSource]]:
    """(cameras, tactile) frame sources by name (not started)."""
    from hardware.cameras import GelSightMini, OpenCVFrameSource

    cams = {n: OpenCVFrameSource(n, c.device, size=tuple(c.size), crop_fraction=c.crop_fraction, fps=c.fps,
                                 max_age_s=c.max_age_s) for n, c in cfg.cameras.items()}
    tac = {n: GelSightMini(n, t.device, background_frames=t.background_frames, size=tuple(t.size),
                           crop_fraction=t.crop_fraction, fps=t.fps, max_age_s=t.max_age_s)
           for n, t in cfg.tactile.items()}
    return cams, tac


@dataclass
class Setup:
    """Connected devices of a setup, ready for :class:`~hardware.control_loop.ControlLoop`."""

    arm: Arm
    gripper: Gripper | None
    cameras: dict[str, FrameSource]
    tactile: dict[str, FrameSource]
    limits: SafetyLimits
    control: ControlLoopConfig


@contextlib.contextmanager
def open_setup(cfg: SetupConfig) -> Iterator[Setup]:
    """Connect the arm, the gripper and start every frame source; on exit close them in reverse order
    (sensors first, the arm last: stopped, then closed)."""
    with contextlib.ExitStack() as stack:
        arm = build_arm(cfg)
        stack.enter_context(arm)
        gripper = build_gripper(cfg, arm)
        if gripper is not None:
            stack.enter_context(gripper)
        cams, tac = build_frame_sources(cfg)
        for src in (*cams.values(), *tac.values()):
            stack.enter_context(src)
        yield Setup(arm, gripper, cams, tac, cfg.limits, cfg.control)
