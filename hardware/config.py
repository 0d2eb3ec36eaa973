"""One YAML file per robot setup: robot, gripper, cameras, tactile sensors, safety limits, loop timing.

``load_setup(path)`` reads and validates it (pydantic dataclasses with ``config=STRICT``, the project's one config
idiom, checked at construction); every error is one line naming the file and the field, formatted by the project's
one formatter :func:`controltac_il.config.one_line` (``setup.yaml: gripper.port: required for a dynamixel gripper``).
Duplicated keys and a missing ``limits`` section (the workspace box is the user's to state) are errors.
Beyond types and ranges, a setup must be physically plausible for its robot (:data:`ARM_MODELS`): the
workspace box within the arm's reach and above its base, the largest step and turn per control period
within 0.25 m/s and 1 rad/s at ``control.rate_hz``, gripper positions and IDs within the device's range,
a controller address the SDK can connect to, sensible rates, a robot's watchdog window between 1.5 periods and
0.5 s with every camera's frame interval at most half of it.
The chunk size and the ensembling decay are the policy's (its checkpoint): a setup file that states them is
refused, and :func:`loop_config` checks the setup's timing against the policy's chunk (the inference deadline
must fit in one chunk) when a deployment builds the loop, before anything connects.
``open_setup(cfg)`` validates the configuration again (devices are never built from an unvalidated one),
connects the devices it describes and closes them again (arm stopped first); a device that cannot be
reached is a :class:`~hardware.interfaces.HardwareError` naming the setup file and the address.
Example files: ``hardware/configs/``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml
from pydantic import Field, TypeAdapter, ValidationError, field_validator, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass

from controltac_il.config import STRICT, FieldErrors, one_line
from hardware.control_loop import ControlLoopConfig, LoopTiming
from hardware.fields import Problems, Str
from hardware.sections import (ARM_MODELS, MODELS_OF, ArmModel, CameraConfig, GripperConfig,  # noqa: F401 - re-exported
                               RobotConfig, TactileConfig)
from hardware.interfaces import Arm, Clock, FrameSource, Gripper, HardwareError, WallClock
from hardware.safety import SafetyLimits


class ConfigError(ValueError):
    """A setup file is malformed; the one-line message names the file and the field."""


MAX_SPEED_M_S = 0.25  # largest end-effector speed a setup may allow (max_step_m * rate_hz)
MAX_TURN_RAD_S = 1.0  # largest yaw rate a setup may allow (max_rotation_rad * rate_hz)
MAX_ROBOT_RATE_HZ = 100.0  # control rate of a real arm (the adapters stream between targets)
MAX_WATCHDOG_S = 0.5  # longest a robot may go without a fresh command or frame before the watchdog stops it
MIN_STALE_PERIODS = 1.5  # below, the watchdog trips between two commands on time
CONNECT_TIMEOUT_S: float | None = 3.0  # an arm controller must accept a TCP connection within this (None: no pre-flight)


POLICY_OWNED = {  # control fields a setup file must not state: the deployed policy's checkpoint sets them
    "chunk_size": "the chunk size is the policy's: deployment takes it from the checkpoint (its config.json "
                  "chunk_size); remove it from the setup file",
    "ensemble_k": "the temporal-ensembling decay is the policy's: deployment takes it from the checkpoint (its "
                  "config.json temporal_ensemble_coeff); remove it from the setup file",
}


@pydantic_dataclass(frozen=True, config=STRICT)
class SetupConfig:
    """A whole setup. name: free text. robot / gripper: see their classes. cameras / tactile: name ->
    device (observation keys images/<name>, tactile/<name>). limits: SafetyLimits fields (required, with
    the workspace box). control: LoopTiming fields (rate_hz, inference, inference_deadline_s, ...); the chunk
    size and the ensembling decay are the policy's (:data:`POLICY_OWNED`). ``source``: the file it was read
    from (named by errors at start-up; "setup" when it was not read from a file)."""

    robot: RobotConfig
    limits: SafetyLimits = Field(None, validate_default=True)
    name: Str = "setup"
    gripper: GripperConfig = Field(default_factory=GripperConfig)
    cameras: dict[Str, CameraConfig] = Field(default_factory=dict)
    tactile: dict[Str, TactileConfig] = Field(default_factory=dict)
    control: LoopTiming = Field(default_factory=LoopTiming)

    @property
    def source(self) -> str:
        return getattr(self, "_source", "setup")

    @field_validator("limits", mode="before")
    @classmethod
    def _box_stated(cls, v):
        problems = Problems("SetupConfig")
        if v is None:
            problems.missing("", "the section is required: state workspace_min and workspace_max (x, y, z in m, "
                                 "base frame); nothing has a default box")
        for key in ("workspace_min", "workspace_max"):
            if isinstance(v, dict) and key not in v:
                problems.missing(key, "required: the box (x, y, z in m, base frame) the end effector must stay in")
        problems.raise_any()
        return v

    @field_validator("control", mode="before")
    @classmethod
    def _control(cls, v, info):
        """Fields the policy owns are refused; a robot's rate bound is named before LoopTiming's wider one
        (which the simulation uses)."""
        problems = Problems("SetupConfig")
        for name, why in POLICY_OWNED.items():
            if isinstance(v, dict) and name in v:
                problems.add(name, why, v[name])
        robot = info.data.get("robot")
        rate = v.get("rate_hz") if isinstance(v, dict) else getattr(v, "rate_hz", None)
        if (robot is not None and robot.type != "sim" and isinstance(rate, (int, float)) and not isinstance(rate, bool)
                and rate > MAX_ROBOT_RATE_HZ):
            problems.add("rate_hz", f"a robot's control rate is at most {MAX_ROBOT_RATE_HZ:g} Hz", rate)
        problems.raise_any()
        return v

    @model_validator(mode="after")
    def _physically_plausible(self):
        """The gripper fits the robot; the box within the arm's reach and above its base; speed and turn per
        period at the control rate; rates a robot can keep. All problems in one error."""
        problems = Problems("SetupConfig")
        if self.gripper.type == "xarm" and self.robot.type != "xarm":
            problems.add("gripper.type", "an xarm gripper needs robot.type xarm", self.gripper.type)
        _box_problems(problems, self.limits, self.robot.arm)
        _rate_problems(problems, self)
        if self.robot.type != "sim":
            _watchdog_problems(problems, self)
        problems.raise_any()
        return self


def _box_problems(problems: Problems, lim: SafetyLimits, arm: ArmModel | None) -> None:
    """The workspace box above the base plane and, for a robot, within its arm's reach and height."""
    lo, hi = np.asarray(lim.workspace_min), np.asarray(lim.workspace_max)
    if lo[2] < 0:
        problems.add("limits.workspace_min", f"z = {lo[2]:g} m is below the robot's base plane (z = 0, its mounting "
                     "surface); the box must start at z >= 0", list(lim.workspace_min))
    if arm is None:
        return
    far = np.where(np.abs(lo[:2]) > np.abs(hi[:2]), lo[:2], hi[:2])  # the box corner farthest from the axis
    r = float(np.hypot(*far))
    if r > arm.reach_m + 1e-9:
        blame = "workspace_min" if (np.abs(lo[:2]) > np.abs(hi[:2])).any() else "workspace_max"
        problems.add(f"limits.{blame}", f"the box corner {np.round(far, 4).tolist()} is {r:.2f} m from the base "
                     f"axis, beyond the reach of {arm.label} ({arm.reach_m:g} m): every corner of "
                     f"workspace_min..workspace_max must lie within {arm.reach_m:g} m of it horizontally",
                     list(getattr(lim, blame)))
    if hi[2] > arm.top_m:
        problems.add("limits.workspace_max", f"z = {hi[2]:g} m is above the highest point {arm.label} reaches "
                     f"({arm.top_m:g} m above its base)", list(lim.workspace_max))


def _rate_problems(problems: Problems, cfg: SetupConfig) -> None:
    """Speed and turn per period within MAX_SPEED_M_S and MAX_TURN_RAD_S at the control rate; the xArm's
    interpolated stream at least as fast as the control rate."""
    lim, rate = cfg.limits, cfg.control.rate_hz
    for name, value, unit, bound, per in (("max_step_m", lim.max_step_m, "m", MAX_SPEED_M_S, "m/s"),
                                          ("max_rotation_rad", lim.max_rotation_rad, "rad", MAX_TURN_RAD_S, "rad/s")):
        if value * rate > bound * (1 + 1e-9):
            problems.add(f"limits.{name}", f"{value:g} {unit} per period at control.rate_hz {rate:g} is "
                         f"{value * rate:.3g} {per}; at most {bound:g} {per} ({name} <= {bound / rate:.4g} at "
                         f"{rate:g} Hz)", value)
    if cfg.robot.type == "xarm" and cfg.robot.stream_hz < rate:
        problems.add("robot.stream_hz", f"must be at least control.rate_hz ({rate:g})", cfg.robot.stream_hz)


def _watchdog_problems(problems: Problems, cfg: SetupConfig) -> None:
    """A robot's watchdog window (stale_after_periods periods) between MIN_STALE_PERIODS periods and
    MAX_WATCHDOG_S, and every camera's frame interval at most half of it (else frames on time would trip it)."""
    control = cfg.control
    window = control.stale_after_periods / control.rate_hz
    if control.stale_after_periods < MIN_STALE_PERIODS:
        problems.add("control.stale_after_periods", f"at least {MIN_STALE_PERIODS:g}: below, the watchdog trips "
                     "between two commands sent on time", control.stale_after_periods)
    elif window > MAX_WATCHDOG_S:
        problems.add("control.stale_after_periods", f"{control.stale_after_periods:g} periods at "
                     f"{control.rate_hz:g} Hz is {window:.3g} s without a command or frame before the arm stops; "
                     f"at most {MAX_WATCHDOG_S:g} s", control.stale_after_periods)
    for section, devices in (("cameras", cfg.cameras), ("tactile", cfg.tactile)):
        for name, device in devices.items():
            if device.fps is not None and 1.0 / device.fps > window / 2:
                problems.add(f"{section}.{name}.fps", f"a frame every {1.0 / device.fps:.3g} s: at most half the "
                             f"watchdog's {window:.3g} s window (a frame's age reaches its interval plus the capture "
                             "latency), else frames on time would stop the arm", device.fps)


# -- reading ---------------------------------------------------------------------------------------

def parse_setup(data: dict, source: str = "setup") -> SetupConfig:
    """Validate a parsed YAML mapping; the error is one line, ``<source>: <field path>: <problem>``."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of sections (robot, limits, gripper, cameras, tactile, "
                          f"control), got {type(data).__name__}")
    try:
        cfg = TypeAdapter(SetupConfig).validate_python(data)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {one_line(exc)}") from None
    object.__setattr__(cfg, "_source", source)  # frozen: set once, here
    return cfg


def validated(cfg: SetupConfig) -> SetupConfig:
    """``cfg`` validated again from its values (a config built without validation or changed after loading
    is caught here): every device builder and :func:`open_setup` go through this first."""
    if not isinstance(cfg, SetupConfig):
        raise ConfigError(f"expected a SetupConfig from load_setup / parse_setup, got {type(cfg).__name__}")
    return parse_setup(_plain_data(cfg), cfg.source)


def _plain_data(v):
    """Dataclasses (every field; of a typed section, its type's fields only: the rest are unused defaults)
    as plain dicts and lists, so that validation runs on every value again."""
    if hasattr(v, "__dataclass_fields__"):
        names = [f.name for f in fields(v)]
        if hasattr(v, "USED") and getattr(v, "type", None) in v.USED:
            names = ["type", *v.USED[v.type]]
        return {k: _plain_data(getattr(v, k)) for k in names if hasattr(v, k)}
    if isinstance(v, dict):
        return {k: _plain_data(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain_data(x) for x in v]
    return v


def loop_config(cfg: SetupConfig, chunk_size: int, ensemble_k: float) -> ControlLoopConfig:
    """The control loop's settings for a policy with ``chunk_size`` and ``ensemble_k`` on this setup; a
    ConfigError naming the file and the field (``control.inference_deadline_s`` in async mode,
    ``control.query_every`` in sync mode) when the setup's timing does not fit the policy's chunk. Deployment calls it before anything connects."""
    try:
        return ControlLoopConfig.for_policy(cfg.control, chunk_size, ensemble_k)
    except (ValidationError, FieldErrors) as exc:
        names = {f.name: f"control.{f.name}" for f in fields(ControlLoopConfig)}
        raise ConfigError(f"{cfg.source}: {one_line(exc, names)}") from None

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
    except (OSError, UnicodeDecodeError) as exc:  # missing, unreadable, or not text (e.g. a weights file)
        raise ConfigError(f"{path}: cannot read the setup file: {exc}") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        if node is not None:
            _refuse_duplicate_keys(node, str(path))
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {one_line(exc)}") from None
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
    control: LoopTiming  # the setup's timing; the loop's chunk size is the policy's (loop_config)
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
