"""One YAML file per robot setup: robot, gripper, cameras, tactile sensors, safety limits, loop timing.

``load_setup(path)`` reads and validates it (pydantic models, checked at construction); every error is
one line naming the file and the field (``setup.yaml: gripper.port: required for a dynamixel gripper``).
Duplicated keys and a missing ``limits`` section (the workspace box is the user's to state) are errors.
Beyond types and ranges, a setup must be physically plausible for its robot (:data:`ARM_MODELS`): the
workspace box within the arm's reach and above its base, the largest step and turn per control period
within 0.25 m/s and 1 rad/s at ``control.rate_hz``, gripper positions and IDs within the device's range,
a controller address the SDK can connect to, sensible rates and deadlines.
``open_setup(cfg)`` validates the configuration again (devices are never built from an unvalidated one),
connects the devices it describes and closes them again (arm stopped first); a device that cannot be
reached is a :class:`~hardware.interfaces.HardwareError` naming the setup file and the address.
Example files: ``hardware/configs/``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Iterator, Literal

import numpy as np
import yaml
from pydantic import BaseModel, Field, PrivateAttr, ValidationError, field_validator, model_validator

from hardware.control_loop import ControlLoopConfig
from hardware.fields import SETTINGS, Bool, Device, Float, Int, IPAddress, Size, Str, Vec2, Vec3, error_line
from hardware.interfaces import Arm, Clock, FrameSource, Gripper, HardwareError, WallClock
from hardware.safety import SafetyLimits


class ConfigError(ValueError):
    """A setup file is malformed; the one-line message names the file and the field."""


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
MAX_SPEED_M_S = 0.25  # largest end-effector speed a setup may allow (max_step_m * rate_hz)
MAX_TURN_RAD_S = 1.0  # largest yaw rate a setup may allow (max_rotation_rad * rate_hz)
MAX_ROBOT_RATE_HZ = 100.0  # control rate of a real arm (the adapters stream between targets)
CONNECT_TIMEOUT_S: float | None = 3.0  # an arm controller must accept a TCP connection within this (None: no pre-flight)


def _fields_used(section: BaseModel, kind: str, used: dict[str, tuple[str, ...]]) -> list[str]:
    """Problems for fields written in the file that the chosen ``type`` does not use (they would be ignored)."""
    own = used[kind]
    article = "an" if kind == "xarm" or kind[0] in "aeiou" else "a"
    what = type(section).__name__.removesuffix("Config").lower()
    return [f"{name}: not used by {article} {kind} {what} (its fields: {', '.join(own) or 'none'})"
            for name in type(section).model_fields
            if name in section.model_fields_set and name != "type" and name not in own]


def _raise(problems: list[str]) -> None:
    if problems:
        raise ValueError("; ".join(problems))


class _Section(BaseModel):
    model_config = SETTINGS


class RobotConfig(_Section):
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

    @model_validator(mode="after")
    def _per_type(self):
        problems = _fields_used(self, self.type, self.USED)
        if self.type in ("xarm", "ur") and self.ip is None:
            problems.append(f"ip: required for robot type {self.type!r} (the controller's IP address)")
        if self.type == "xarm" and self.ip is not None and ":" in self.ip:
            problems.append(f"ip: the xArm SDK connects over IPv4 only: expected an address such as 192.168.1.221, "
                            f"got {self.ip!r}")
        if self.type == "ur" and self.model is None:
            problems.append(f"model: required for a UR arm (its reach bounds the workspace): one of "
                            f"{', '.join(MODELS_OF['ur'])}")
        if self.type in MODELS_OF and self.model is not None and self.model not in MODELS_OF[self.type]:
            problems.append(f"model: {self.model!r} is not an {self.type} model: one of {', '.join(MODELS_OF[self.type])}")
        _raise(problems)
        return self

    @property
    def arm(self) -> ArmModel | None:
        """The arm's reach figures (an xarm without ``model`` is any xArm 5/6/7: they share them); None for sim."""
        if self.type == "sim":
            return None
        return ARM_MODELS[self.model or "xarm7"]


class GripperConfig(_Section):
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

    @model_validator(mode="after")
    def _per_type(self):
        problems = _fields_used(self, self.type, self.USED)
        if self.type in ("dynamixel", "robotiq") and not self.port:
            problems.append(f"port: required for a {self.type} gripper (e.g. /dev/serial/by-id/usb-...)")
        if self.type == "dynamixel" and (self.open_position is None or self.closed_position is None):
            problems.append("open_position: open_position and closed_position (Goal Position ticks) are "
                            "required for a dynamixel gripper")
        positions = [(n, getattr(self, n)) for n in ("open_position", "closed_position") if getattr(self, n) is not None]
        if self.type == "dynamixel":
            lo, hi = self.DXL_TICKS
            for name, v in positions:
                if not float(v).is_integer():
                    problems.append(f"{name}: Goal Position ticks are whole numbers, got {v}")
                elif not lo <= v <= hi:
                    problems.append(f"{name}: a Dynamixel Goal Position within one turn is {lo}..{hi} ticks, got {v:g}")
        if self.type == "xarm":
            lo, hi = self.XARM_POSITIONS
            problems += [f"{name}: an xArm gripper position is {lo}..{hi} (SDK units), got {v:g}"
                         for name, v in positions if not lo <= v <= hi]
            if self.speed is not None and not self.XARM_SPEED[0] <= self.speed <= self.XARM_SPEED[1]:
                problems.append(f"speed: an xArm gripper speed is {self.XARM_SPEED[0]}..{self.XARM_SPEED[1]} (r/min), "
                                f"got {self.speed}")
        if self.open_position is not None and self.open_position == self.closed_position:
            problems.append("closed_position: must differ from open_position")
        if self.type == "robotiq" and self.speed is not None and self.speed > 255:
            problems.append(f"speed: a Robotiq speed is 0-255, got {self.speed}")
        _raise(problems)
        return self


class CameraConfig(_Section):
    """device: /dev/videoN, an index, a name fragment under /dev/v4l/by-id, or a video file.
    size: output [H, W]. fps: requested rate. crop_fraction: border removed from each side.
    max_age_s: the newest frame may be this old before the camera counts as stalled (None: loop watchdog only)."""

    device: Device
    size: Size = (240, 320)
    fps: Float | None = Field(30.0, gt=0, le=240)
    crop_fraction: Float = Field(0.0, ge=0, lt=0.5)
    max_age_s: Float | None = Field(None, gt=0)


class TactileConfig(CameraConfig):
    """A GelSight Mini: as a camera, with the 15 % crop, 25 fps and a background over ``background_frames``
    no-contact frames at start (default device: the only "GelSight Mini" under /dev/v4l/by-id)."""

    device: Device = "GelSight Mini"
    fps: Float | None = Field(25.0, gt=0, le=240)
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
    _source: str = PrivateAttr("setup")  # the file it was read from (named by errors at start-up)

    @property
    def source(self) -> str:
        """The file this setup was read from ("setup" when it was not read from a file)."""
        return (getattr(self, "__pydantic_private__", None) or {}).get("_source") or "setup"

    @field_validator("limits", mode="before")
    @classmethod
    def _box_stated(cls, v):
        if v is None:
            raise ValueError("the section is required: state workspace_min and workspace_max (x, y, z in m, base frame)")
        for key in ("workspace_min", "workspace_max"):
            if isinstance(v, dict) and key not in v:
                raise ValueError(f"{key}: required: the box (x, y, z in m, base frame) the end effector must stay in")
        return v

    @field_validator("control", mode="before")
    @classmethod
    def _robot_rate(cls, v, info):
        """A robot's rate bound is named before ControlLoopConfig's wider one (which the simulation uses)."""
        robot = info.data.get("robot")
        rate = v.get("rate_hz") if isinstance(v, dict) else getattr(v, "rate_hz", None)
        if (robot is not None and robot.type != "sim" and isinstance(rate, (int, float)) and not isinstance(rate, bool)
                and rate > MAX_ROBOT_RATE_HZ):
            raise ValueError(f"rate_hz: a robot's control rate is at most {MAX_ROBOT_RATE_HZ:g} Hz, got {rate:g}")
        return v

    @model_validator(mode="after")
    def _gripper_fits_robot(self):
        if self.gripper.type == "xarm" and self.robot.type != "xarm":
            raise ValueError("gripper.type: an xarm gripper needs robot.type xarm")
        return self

    @model_validator(mode="after")
    def _physically_plausible(self):
        """The box within the arm's reach and above its base; speed and turn per period at the control
        rate; rates and the inference deadline a robot can keep. All problems in one message."""
        lim, ctl, arm = self.limits, self.control, self.robot.arm
        lo, hi = np.asarray(lim.workspace_min), np.asarray(lim.workspace_max)
        problems = []
        if lo[2] < 0:
            problems.append(f"limits.workspace_min: z = {lo[2]:g} m is below the robot's base plane (z = 0, its "
                            "mounting surface); the box must start at z >= 0")
        if arm is not None:
            far = np.where(np.abs(lo[:2]) > np.abs(hi[:2]), lo[:2], hi[:2])  # the box corner farthest from the axis
            r = float(np.hypot(*far))
            if r > arm.reach_m + 1e-9:
                blame = "workspace_min" if (np.abs(lo[:2]) > np.abs(hi[:2])).any() else "workspace_max"
                problems.append(f"limits.{blame}: the box corner {np.round(far, 4).tolist()} is {r:.2f} m from the base "
                                f"axis, beyond the reach of {arm.label} ({arm.reach_m:g} m): every corner of "
                                f"workspace_min..workspace_max must lie within {arm.reach_m:g} m of it horizontally")
            if hi[2] > arm.top_m:
                problems.append(f"limits.workspace_max: z = {hi[2]:g} m is above the highest point {arm.label} "
                                f"reaches ({arm.top_m:g} m above its base)")
        rate = ctl.rate_hz
        if self.robot.type != "sim" and rate > MAX_ROBOT_RATE_HZ:
            problems.append(f"control.rate_hz: a robot's control rate is at most {MAX_ROBOT_RATE_HZ:g} Hz, got {rate:g}")
        for name, value, unit, bound, per in (("max_step_m", lim.max_step_m, "m", MAX_SPEED_M_S, "m/s"),
                                              ("max_rotation_rad", lim.max_rotation_rad, "rad", MAX_TURN_RAD_S, "rad/s")):
            if value * rate > bound * (1 + 1e-9):
                problems.append(f"limits.{name}: {value:g} {unit} per period at control.rate_hz {rate:g} is "
                                f"{value * rate:.3g} {per}; at most {bound:g} {per} ({name} <= {bound / rate:.4g} "
                                f"at {rate:g} Hz)")
        if self.robot.type == "xarm" and self.robot.stream_hz < rate:
            problems.append(f"robot.stream_hz: must be at least control.rate_hz ({rate}), got {self.robot.stream_hz:g}")
        chunk_s = ctl.chunk_size * ctl.period_s
        if ctl.inference_deadline_s > chunk_s + 1e-9:
            problems.append(f"control.inference_deadline_s: {ctl.inference_deadline_s:g} s is longer than one chunk "
                            f"(chunk_size {ctl.chunk_size} x {ctl.period_s:g} s = {chunk_s:g} s), so it would never "
                            f"fire; at most {chunk_s:g} s")
        _raise(problems)
        return self


# -- reading ---------------------------------------------------------------------------------------

def parse_setup(data: dict, source: str = "setup") -> SetupConfig:
    """Validate a parsed YAML mapping; the error is one line, ``<source>: <field path>: <problem>``."""
    try:
        cfg = SetupConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(error_line(exc, source)) from None
    cfg._source = source
    return cfg


def validated(cfg: SetupConfig) -> SetupConfig:
    """``cfg`` validated again from its values (a config built with ``model_construct`` or changed after
    loading is caught here): every device builder and :func:`open_setup` go through this first."""
    if not isinstance(cfg, SetupConfig):
        raise ConfigError(f"expected a SetupConfig from load_setup / parse_setup, got {type(cfg).__name__}")
    return parse_setup(_plain_data(cfg), cfg.source)


def _plain_data(v):
    """Models (the fields written) and pydantic dataclasses (every field) as plain dicts and lists, so that
    validation runs on every value again."""
    if isinstance(v, BaseModel):
        return {k: _plain_data(getattr(v, k)) for k in type(v).model_fields if k in v.model_fields_set and hasattr(v, k)}
    if hasattr(v, "__pydantic_fields__"):  # a pydantic dataclass (SafetyLimits, ControlLoopConfig)
        return {k: _plain_data(getattr(v, k)) for k in v.__pydantic_fields__ if hasattr(v, k)}
    if isinstance(v, dict):
        return {k: _plain_data(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain_data(x) for x in v]
    return v


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
    """The arm adapter described by ``cfg.robot`` (not connected; ``cfg`` validated again first);
    ``clock`` defaults to the wall clock."""
    cfg = validated(cfg)
    r = cfg.robot
    if r.type == "xarm":
        from hardware.xarm import XArm

        return XArm(r.ip, tool_rpy=r.tool_rpy, period_s=cfg.control.period_s, stream_hz=r.stream_hz,
                    stop_on_warning=r.stop_on_warning, clock=clock, connect_timeout_s=CONNECT_TIMEOUT_S)
    if r.type == "ur":
        from hardware.ur import URArm

        return URArm(r.ip, tool_rotvec=r.tool_rotvec, period_s=cfg.control.period_s,
                     lookahead_time=r.lookahead_time, gain=r.gain, clock=clock, connect_timeout_s=CONNECT_TIMEOUT_S)
    raise ConfigError("robot.type: 'sim' is the MuJoCo scene; it is built by the deploy script (--robot sim)")


def build_gripper(cfg: SetupConfig, arm: Arm, clock: Clock | None = None) -> Gripper | None:
    """The gripper adapter described by ``cfg.gripper`` (not connected; ``cfg`` validated again first), or None."""
    cfg = validated(cfg)
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
    """(cameras, tactile) frame sources by name (not started; ``cfg`` validated again first)."""
    from hardware.cameras import GelSightMini, OpenCVFrameSource

    cfg = validated(cfg)
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
    """Validate ``cfg`` again (ConfigError naming the file), then connect the arm, the gripper and start
    every frame source, all on ``clock`` (default: the wall clock); on exit close them in reverse order
    (sensors first, the arm last: stopped, then closed). A device that cannot be reached or started raises
    its :class:`~hardware.interfaces.HardwareError` with the setup file named in front."""
    cfg = validated(cfg)  # before anything connects
    source = cfg.source
    clock = clock or WallClock()
    with contextlib.ExitStack() as stack:
        try:
            arm = build_arm(cfg, clock)
            stack.enter_context(arm)
            gripper = build_gripper(cfg, arm, clock)
            if gripper is not None:
                stack.enter_context(gripper)
            cams, tac = build_frame_sources(cfg, clock)
            for src in (*cams.values(), *tac.values()):
                stack.enter_context(src)
        except HardwareError as exc:
            raise type(exc)(f"{source}: {exc}") from exc
        yield Setup(arm, gripper, cams, tac, cfg.limits, cfg.control, clock)
