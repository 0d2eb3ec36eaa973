"""One YAML file per robot setup: robot, gripper, cameras, tactile sensors, safety limits, loop timing.

``load_setup(path)`` reads and validates it (pydantic models, checked at construction); every error is
one line naming the file and the field (``setup.yaml: gripper.port: required for a dynamixel gripper``).
Duplicated keys and a missing ``limits`` section (the workspace box is the user's to state) are errors.
``open_setup(cfg)`` connects the devices it describes and closes them again (arm stopped first).
Example files: ``hardware/configs/``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal

import numpy as np
import yaml
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from hardware.control_loop import ControlLoopConfig
from hardware.fields import SETTINGS, Bool, Device, Float, Int, IPAddress, Size, Str, Vec2, Vec3, error_line
from hardware.interfaces import Arm, Clock, FrameSource, Gripper, WallClock
from hardware.safety import SafetyLimits


class ConfigError(ValueError):
    """A setup file is malformed; the one-line message names the file and the field."""


class _Section(BaseModel):
    model_config = SETTINGS


class RobotConfig(_Section):
    """type: "xarm", "ur" or "sim" (the MuJoCo scene; built by the deploy script, not here).
    ip: controller IP address (xarm, ur). tool_rpy: xArm tool (roll, pitch) at yaw 0, rad.
    tool_rotvec: UR tool orientation at yaw 0 as a rotation vector. lookahead_time, gain: UR servoL
    settings. stream_hz: rate of the interpolated xArm servo points between two control targets.
    stop_on_warning: xArm controller warnings stop the run too."""

    type: Literal["xarm", "ur", "sim"]
    ip: IPAddress | None = None
    tool_rpy: Vec2 = (float(np.pi), 0.0)
    tool_rotvec: Vec3 = (float(np.pi), 0.0, 0.0)
    lookahead_time: Float = Field(0.1, ge=0.03, le=0.2)
    gain: Float = Field(300.0, ge=100, le=2000)
    stream_hz: Float = Field(100.0, ge=10, le=250)
    stop_on_warning: Bool = False

    @model_validator(mode="after")
    def _ip_for_a_real_arm(self):
        if self.type in ("xarm", "ur") and self.ip is None:
            raise ValueError(f"ip: required for robot type {self.type!r} (the controller's IP address)")
        return self


class GripperConfig(_Section):
    """type: "none", "xarm" (needs an xarm robot), "dynamixel" or "robotiq".
    port: serial device (dynamixel, robotiq), preferably /dev/serial/by-id/....
    baudrate: bus speed (default 57600 dynamixel, 115200 robotiq).
    dxl_id, open_position, closed_position, goal_current: Dynamixel servo ID, Goal Position ticks when
    open / closed, squeeze limit (~2.69 mA units). xArm gripper: open/closed in SDK units (850 / 0).
    slave_id, force: Robotiq Modbus address (9) and grip force (0-255).
    speed: Robotiq 0-255 (default 255); xArm gripper pulse/s (default 5000)."""

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

    @model_validator(mode="after")
    def _per_type(self):
        if self.type in ("dynamixel", "robotiq") and not self.port:
            raise ValueError(f"port: required for a {self.type} gripper (e.g. /dev/serial/by-id/usb-...)")
        if self.type == "dynamixel" and (self.open_position is None or self.closed_position is None):
            raise ValueError("open_position: open_position and closed_position (Goal Position ticks) are "
                             "required for a dynamixel gripper")
        if self.open_position is not None and self.open_position == self.closed_position:
            raise ValueError("closed_position: must differ from open_position")
        if self.type == "robotiq" and self.speed is not None and self.speed > 255:
            raise ValueError(f"speed: a Robotiq speed is 0-255, got {self.speed}")
        return self


class CameraConfig(_Section):
    """device: /dev/videoN, an index, a name fragment under /dev/v4l/by-id, or a video file.
    size: output [H, W]. fps: requested rate. crop_fraction: border removed from each side.
    max_age_s: the newest frame may be this old before the camera counts as stalled (None: loop watchdog only)."""

    device: Device
    size: Size = (240, 320)
    fps: Float | None = Field(30.0, gt=0, le=1000)
    crop_fraction: Float = Field(0.0, ge=0, lt=0.5)
    max_age_s: Float | None = Field(None, gt=0)


class TactileConfig(CameraConfig):
    """A GelSight Mini: as a camera, with the 15 % crop, 25 fps and a background over ``background_frames``
    no-contact frames at start (default device: the only "GelSight Mini" under /dev/v4l/by-id)."""

    device: Device = "GelSight Mini"
    fps: Float | None = Field(25.0, gt=0, le=1000)
    crop_fraction: Float = Field(0.15, ge=0, lt=0.5)
    background_frames: Int = Field(30, ge=1)


class SetupConfig(_Section):
    """A whole setup. name: free text. robot / gripper: see their classes. cameras / tactile: name ->
    device (observation keys images/<name>, tactile/<name>). limits: SafetyLimits fields (required, with
    the workspace box). control: ControlLoopConfig fields (rate_hz, inference, inference_deadline_s, ...)."""

    robot: RobotConfig
    limits: SafetyLimits
    name: Str = "setup"
    gripper: GripperConfig = GripperConfig()
    cameras: dict[Str, CameraConfig] = {}
    tactile: dict[Str, TactileConfig] = {}
    control: ControlLoopConfig = ControlLoopConfig()

    @field_validator("limits", mode="before")
    @classmethod
    def _box_stated(cls, v):
        if v is None:
            raise ValueError("the section is required: state workspace_min and workspace_max (x, y, z in m, base frame)")
        for key in ("workspace_min", "workspace_max"):
            if isinstance(v, dict) and key not in v:
                raise ValueError(f"{key}: required: the box (x, y, z in m, base frame) the end effector must stay in")
        return v

    @model_validator(mode="after")
    def _gripper_fits_robot(self):
        if self.gripper.type == "xarm" and self.robot.type != "xarm":
            raise ValueError("gripper.type: an xarm gripper needs robot.type xarm")
        return self


# -- reading ---------------------------------------------------------------------------------------

def parse_setup(data: dict, source: str = "setup") -> SetupConfig:
    """Validate a parsed YAML mapping; the error is one line, ``<source>: <field path>: <problem>``."""
    try:
        return SetupConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(error_line(exc, source)) from None


def _refuse_duplicate_keys(node: yaml.Node, source: str, path: str = "") -> None:
    """Raise ConfigError at the first mapping key written twice (YAML would silently keep the last)."""
    if isinstance(node, yaml.MappingNode):
        seen: dict[tuple, int] = {}
        for key_node, value in node.value:
            key = (key_node.tag, key_node.value) if isinstance(key_node, yaml.ScalarNode) else None
            sub = f"{path}.{key_node.value}" if path else str(key_node.value)
            line = key_node.start_mark.line + 1
            if key is not None and key_node.value != "<<":
                if key in seen:
                    raise ConfigError(f"{source}: {sub}: duplicated key (lines {seen[key]} and {line})")
                seen[key] = line
            _refuse_duplicate_keys(value, source, sub)
    elif isinstance(node, yaml.SequenceNode):
        for i, value in enumerate(node.value):
            _refuse_duplicate_keys(value, source, f"{path}[{i}]")


def load_setup(path: str | Path) -> SetupConfig:
    """Read and validate a setup YAML file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the setup file: {exc}") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        if node is not None:
            _refuse_duplicate_keys(node, str(path))
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    return parse_setup(data if data is not None else {}, str(path))


# -- building devices ------------------------------------------------------------------------------

def build_arm(cfg: SetupConfig, clock: Clock | None = None) -> Arm:
    """The arm adapter described by ``cfg.robot`` (not connected); ``clock`` defaults to the wall clock."""
    r = cfg.robot
    if r.type == "xarm":
        from hardware.xarm import XArm

        return XArm(r.ip, tool_rpy=r.tool_rpy, period_s=cfg.control.period_s,
                    stream_hz=max(r.stream_hz, cfg.control.rate_hz), stop_on_warning=r.stop_on_warning, clock=clock)
    if r.type == "ur":
        from hardware.ur import URArm

        return URArm(r.ip, tool_rotvec=r.tool_rotvec, period_s=cfg.control.period_s,
                     lookahead_time=r.lookahead_time, gain=r.gain, clock=clock)
    raise ConfigError("robot.type: 'sim' is the MuJoCo scene; it is built by the deploy script (--robot sim)")


def build_gripper(cfg: SetupConfig, arm: Arm, clock: Clock | None = None) -> Gripper | None:
    """The gripper adapter described by ``cfg.gripper`` (not connected), or None."""
    g = cfg.gripper
    if g.type == "none":
        return None
    if g.type == "xarm":
        from hardware.xarm import XArmGripper

        extra = {k: v for k, v in (("open_position", g.open_position), ("closed_position", g.closed_position)) if v is not None}
        return XArmGripper(arm, speed=float(g.speed or 5000), clock=clock, **extra)
    if g.type == "dynamixel":
        from hardware.dynamixel import DynamixelGripper

        return DynamixelGripper(g.port, dxl_id=g.dxl_id, baudrate=g.baudrate or 57600,
                                open_position=int(g.open_position), closed_position=int(g.closed_position),
                                goal_current=g.goal_current, clock=clock)
    from hardware.robotiq import RobotiqGripper

    return RobotiqGripper(g.port, slave_id=g.slave_id, baudrate=g.baudrate or 115200,
                          speed=255 if g.speed is None else g.speed, force=g.force, clock=clock)


def build_frame_sources(cfg: SetupConfig, clock: Clock | None = None
                        ) -> tuple[dict[str, FrameSource], dict[str, FrameSource]]:
    """(cameras, tactile) frame sources by name (not started)."""
    from hardware.cameras import GelSightMini, OpenCVFrameSource

    cams = {n: OpenCVFrameSource(n, c.device, size=c.size, crop_fraction=c.crop_fraction, fps=c.fps,
                                 max_age_s=c.max_age_s, clock=clock) for n, c in cfg.cameras.items()}
    tac = {n: GelSightMini(n, t.device, background_frames=t.background_frames, size=t.size,
                           crop_fraction=t.crop_fraction, fps=t.fps, max_age_s=t.max_age_s, clock=clock)
           for n, t in cfg.tactile.items()}
    return cams, tac


@dataclass
class Setup:
    """Connected devices of a setup, ready for :class:`~hardware.control_loop.ControlLoop`
    (``ControlLoop(setup.arm, policy, gripper=setup.gripper, ..., clock=setup.clock)``)."""

    arm: Arm
    gripper: Gripper | None
    cameras: dict[str, FrameSource]
    tactile: dict[str, FrameSource]
    limits: SafetyLimits
    control: ControlLoopConfig
    clock: Clock = field(default_factory=WallClock)


@contextlib.contextmanager
def open_setup(cfg: SetupConfig, clock: Clock | None = None) -> Iterator[Setup]:
    """Connect the arm, the gripper and start every frame source, all on ``clock`` (default: the wall
    clock); on exit close them in reverse order (sensors first, the arm last: stopped, then closed)."""
    clock = clock or WallClock()
    with contextlib.ExitStack() as stack:
        arm = build_arm(cfg, clock)
        stack.enter_context(arm)
        gripper = build_gripper(cfg, arm, clock)
        if gripper is not None:
            stack.enter_context(gripper)
        cams, tac = build_frame_sources(cfg, clock)
        for src in (*cams.values(), *tac.values()):
            stack.enter_context(src)
        yield Setup(arm, gripper, cams, tac, cfg.limits, cfg.control, clock)
