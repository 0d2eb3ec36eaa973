"""``PegInHoleEnv``: the MuJoCo peg-in-hole scene with tactile fingers as a ``gymnasium.Env``.

Action (5,) (``action_space``, a float64 Box): absolute end-effector target [x, y, z, yaw] (m, rad; TCP
between the gel centres, world frame) and a gripper command in [0, 1] (0 = open, 1 = closed): the
action space of the robot adapters. Its bounds are the model's: the hand actuators' ``ctrlrange``
(the config's workspace) and, for the gripper, the fingers' ``ctrlrange`` mapped to [0, 1]. Within
one control step the servo target moves linearly from the previous target to the new one (the
robot's own interpolation), then holds.

Observation dict (``observation_space``, a ``spaces.Dict`` of exactly these keys):
    qpos            float32 (5,): TCP [x, y, z, yaw] and gripper closure in [0, 1]
    images/<cam>    uint8 (H, W, 3) for each configured camera
    tactile/<s>     uint8 (H, W, 3) for s in ("left", "right") when ``config.tactile``
    force/<s>       float32 (3,): [Fx, Fy, Fz] N on each gel in its sensor frame (Fz > 0 pressing)

``render_mode="rgb_array"``: ``render()`` returns the third-view camera's image (``camera_size``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from contextlib import contextmanager
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from controltac_il.extras import require
from controltac_il.streams import LOOP, LOOP_STATE, force_key, image_key, tactile_key

gym = require("gymnasium", "sim", "the MuJoCo scene")
spaces = gym.spaces
os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the first mujoco import
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
mujoco = require("mujoco", "sim", "the MuJoCo scene")

from envs.config import SENSORS, PegInHoleConfig  # noqa: E402
from envs.geometry import rim_height_m  # noqa: E402
from envs.scene import HAND_ACTUATORS, build_model  # noqa: E402
from envs.tactile_rig import PadRays, group_mask, pad_force  # noqa: E402
from hardware.interfaces import ACTION_DIM, GRIPPER, POSE_DIM  # noqa: E402

PEG_RAYS = group_mask(1)  # the peg's geom group
WORLD_RAYS = group_mask(0, 3)  # table, hole floor, gripper (0) and the receptacle's collision walls (3)
RENDER_CAMERA = "third_view"  # what render() shows


class PegInHoleEnv(gym.Env):
    """MuJoCo peg-in-hole scene. See the module docstring for the action and observation spaces.

    config: the scene (``PegInHoleConfig``); render_mode: None or "rgb_array" (``render()``).
    Episode randomisation (``reset(seed=...)``, drawn from ``np_random``): peg position and yaw, hole
    position, grip force (``config.grip_force_range_n``); the in-hand offset comes from where the
    policy grasps, or, with ``config.peg_in_hand``, is drawn (``in_hand_offset_m``, privileged).
    ``info`` holds ``success``, ``clipped`` (the action was outside ``action_space``: a target outside
    the workspace or a gripper command outside [0, 1]), ``grip_force_n``, ``insertion_mm``,
    ``max_penetration_mm`` (deepest peg contact with the receptacle or table) and ``episode_seed``.
    The scene's dimensions come from the compiled model (the MJCF owns them): ``peg_radius_m``,
    ``peg_half_length_m`` (geom "peg") and ``home_tcp`` (the "home" keyframe's hand pose).
    A context manager: leaving the ``with`` block calls ``close()``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    action_dim = qpos_dim = ACTION_DIM  # hardware.interfaces.ACTION_NAMES: [x, y, z, yaw, gripper]

    def __init__(self, config: PegInHoleConfig | None = None, render_mode: str | None = None):
        self.config = config or PegInHoleConfig()
        cfg = self.config
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": cfg.control_hz}
        self.model = build_model(cfg.hole_diameter_mm, cfg.hole_depth_mm, cfg.ring_segments, cfg.camera_size,
                                 cfg.hole_chamfer_mm, cfg.camera_layout, (cfg.workspace_low, cfg.workspace_high))
        self.data = mujoco.MjData(self.model)
        self._index_model()
        self.action_space, self.observation_space = self._spaces()
        self._renderer = None
        if cfg.cameras or render_mode == "rgb_array":
            self._renderer = mujoco.Renderer(self.model, cfg.camera_size[0], cfg.camera_size[1])
        self._sensors: dict = {}
        self._rays: dict[str, PadRays] = {}
        self._backgrounds: dict[str, np.ndarray] = {}
        if cfg.tactile:
            self._init_tactile()
        self._pool = ThreadPoolExecutor(len(SENSORS), thread_name_prefix="tactile") if cfg.tactile else None
        self._episode_seed = 0
        self.hole_xy = np.zeros(2)
        self.grip_force_n = 0.0
        self.in_hand_offset_m: float | None = None
        self._target = np.array([*self._home, 0.0])
        self._steps = 0

    def _index_model(self) -> None:
        """Look up the ids and addresses the env reads and writes, the peg's size and the home keyframe."""
        m = self.model
        self._jnt = {n: m.joint(n).qposadr[0] for n in (*HAND_ACTUATORS, "left_finger", "right_finger")}
        self._act = {m.actuator(i).name: i for i in range(m.nu)}
        self._peg_body = m.body("peg").id
        self._peg_qpos = m.joint("peg").qposadr[0]
        self._peg_geom = m.geom("peg").id
        self.peg_radius_m, self.peg_half_length_m = (float(v) for v in m.geom_size[self._peg_geom][:2])
        self._receptacle = m.body("receptacle").id
        self._gel = {s: m.geom(f"{s}_gel").id for s in SENSORS}
        self._sensor_site = {s: m.site(f"{s}_sensor").id for s in SENSORS}
        self._finger_body = {s: m.body(f"{s}_finger").id for s in SENSORS}
        # contact sensors (MJCF): [found, dist] of the peg's deepest contact with receptacle / table
        self._contact_dist = [m.sensor_adr[m.sensor(n).id] + 1 for n in ("peg_receptacle", "peg_table")]
        self._pose_act = [self._act[n] for n in HAND_ACTUATORS]
        self._finger_act = [self._act[f"{s}_finger"] for s in SENSORS]
        # gripper command 0 / 1 = the finger servos' open / closed target (gel surface from the TCP
        # plane; closed lies inside the peg, so a grasp saturates at the grip force)
        self._finger_closed, self._finger_open = (float(v) for v in m.actuator_ctrlrange[self._finger_act[0]])
        self._home_key = m.key("home").id
        self._home = m.key_qpos[self._home_key][[self._jnt[n] for n in HAND_ACTUATORS]].copy()

    def _spaces(self) -> tuple[spaces.Box, spaces.Dict]:
        """Action space from the actuators' ctrlrange; observation space of the keys ``_observe`` returns."""
        cfg = self.config
        ctrl = self.model.actuator_ctrlrange[self._pose_act]
        action = spaces.Box(np.array([*ctrl[:, 0], 0.0]), np.array([*ctrl[:, 1], 1.0]), dtype=np.float64)
        inf = np.inf
        obs = {LOOP_STATE: spaces.Box(np.array([-inf, -inf, -inf, -inf, 0.0], np.float32),
                                      np.array([inf, inf, inf, inf, 1.0], np.float32), dtype=np.float32)}
        for cam in cfg.cameras:
            obs[image_key(cam, LOOP)] = spaces.Box(0, 255, (*cfg.camera_size, 3), dtype=np.uint8)
        for s in SENSORS:
            if cfg.tactile:
                obs[tactile_key(s, LOOP)] = spaces.Box(0, 255, (*cfg.tactile_size, 3), dtype=np.uint8)
            obs[force_key(s, LOOP)] = spaces.Box(-inf, inf, (3,), dtype=np.float32)
        return action, spaces.Dict(obs)

    def _init_tactile(self) -> None:
        """One sensor model, ray caster and no-contact background per finger."""
        from controltac_il.tactile import SensorSpec, TactileSensor

        cfg = self.config
        spec = SensorSpec.gelsight_mini().scaled(*cfg.tactile_size)
        flat = np.zeros(cfg.tactile_size, np.float32)
        quiet_spec = dataclasses.replace(spec, noise_std=0.0)
        for k, s in enumerate(SENSORS):
            quiet = TactileSensor(quiet_spec, optics=cfg.tactile_optics)
            self._sensors[s] = TactileSensor(spec, optics=cfg.tactile_optics, seed=k) if cfg.tactile_noise else quiet
            self._rays[s] = PadRays(self.model, self.data, f"{s}_sensor", cfg.tactile_size, spec.pad_size_mm,
                                    cfg.ray_stride)
            # no-contact frame = the optics over a flat gel without noise (the optics' flat-gel
            # response is not exactly the raw background for every optics model)
            self._backgrounds[s] = quiet.render_penetration(flat)

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode; returns (observation, info). ``seed`` seeds ``np_random`` and so fixes
        every random draw (None: continue the current generator). No ``options`` are defined."""
        if options:
            raise ValueError(f"PegInHoleEnv.reset takes no options, got {options!r}")
        super().reset(seed=seed)
        self._episode_seed = int(seed) if seed is not None else int(self.np_random.integers(2**31))
        self._start_episode()
        self._steps = 0
        info = {"success": False, "clipped": False, "grip_force_n": self.grip_force_n,
                "insertion_mm": self.insertion_mm(), "max_penetration_mm": 0.0, "episode_seed": self._episode_seed}
        if self.config.peg_in_hand:
            info["in_hand_offset_mm"] = self.in_hand_offset_m * 1000.0
        return self._observe(), info

    def _start_episode(self) -> None:
        """Draw the episode from ``np_random``, pose the scene from the home keyframe, let it settle."""
        cfg, m, d = self.config, self.model, self.data
        rng = self.np_random
        peg_xy = np.array([rng.uniform(*cfg.peg_xy_range_m[0]), rng.uniform(*cfg.peg_xy_range_m[1])])
        peg_yaw = rng.uniform(*cfg.peg_yaw_range_rad)
        self.hole_xy = np.array([rng.uniform(*cfg.hole_xy_range_m[0]), rng.uniform(*cfg.hole_xy_range_m[1])])
        self.grip_force_n = float(rng.uniform(*cfg.grip_force_range_n))
        mujoco.mj_resetDataKeyframe(m, d, self._home_key)  # hand at home, fingers open, peg upright
        m.body_pos[self._receptacle] = [*self.hole_xy, 0.0]
        for s in SENSORS:
            m.actuator_forcerange[self._act[f"{s}_finger"]] = [-self.grip_force_n, self.grip_force_n]
        q = self._peg_qpos
        d.qpos[q + 3:q + 7] = [math.cos(peg_yaw / 2), 0.0, 0.0, math.sin(peg_yaw / 2)]
        if cfg.peg_in_hand:
            # hand over the start point, peg between the closed fingers, its axis off the TCP along the gel
            self.in_hand_offset_m = float(rng.choice((-1.0, 1.0)) * rng.uniform(*cfg.in_hand_offset_mm)) / 1000.0
            home = np.array([*peg_xy, self._home[2], self._home[3]])
            top = home[2] + cfg.grasp_depth_mm / 1000.0
            d.qpos[q:q + 3] = [peg_xy[0] + self.in_hand_offset_m, peg_xy[1], top - self.peg_half_length_m]
            d.qpos[self._jnt["left_finger"]] = d.qpos[self._jnt["right_finger"]] = self.peg_radius_m
            closing = 1.0
        else:
            self.in_hand_offset_m = None
            home = self._home
            d.qpos[q:q + 3] = [*peg_xy, self.peg_half_length_m]
            closing = 0.0  # the keyframe's fingers are open
        for name, value in zip(HAND_ACTUATORS, home):
            d.qpos[self._jnt[name]] = value
        self._target = np.array([*home, closing])
        d.ctrl[:] = self._ctrl_vector(self._target)
        with mujoco_warnings() as said:
            mujoco.mj_forward(m, d)
            for _ in range(cfg.substeps):  # let the peg settle on the table or in the grip
                mujoco.mj_step(m, d)
        self._check_stable(said, f"while episode {self._episode_seed} settled")

    def step(self, action) -> tuple[dict, float, bool, bool, dict]:
        """Apply one control step; returns (observation, reward, terminated, truncated, info).

        Raises ValueError on an action that is not 5 finite numbers. An action outside
        ``action_space`` is clipped to it (the target the servos then hold, ``command``) and flagged
        in ``info["clipped"]``; the actuators' ctrlrange bounds the controls in the model as well.
        """
        target, clipped = self.check_action(action)
        m, d = self.model, self.data
        n = self.config.substeps
        # the servo targets are affine in the action, so interpolating controls interpolates targets
        c0, c1 = self._ctrl_vector(self._target), self._ctrl_vector(target)
        ctrls = c0 + (c1 - c0) * (np.arange(1, n + 1) / n)[:, None]
        max_pen = 0.0
        with mujoco_warnings() as said:
            for k in range(n):
                d.ctrl[:] = ctrls[k]
                mujoco.mj_step(m, d)
                max_pen = max(max_pen, self._peg_static_penetration())
        self._target = target
        self._steps += 1
        self._check_stable(said, f"at step {self._steps}")
        success = self.is_success()
        info = {"success": success, "clipped": clipped, "grip_force_n": self.grip_force_n,
                "insertion_mm": self.insertion_mm(), "max_penetration_mm": max_pen * 1000.0,
                "episode_seed": self._episode_seed}
        truncated = self._steps >= self.config.max_steps and not success
        return self._observe(), float(success), success, truncated, info

    def check_action(self, action) -> tuple[np.ndarray, bool]:
        """Validate an action; returns (float64 (5,) clipped to ``action_space``, whether it was clipped)."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be 5 numbers [x, y, z, yaw, gripper], got {action!r}") from None
        if a.shape != (self.action_dim,):
            raise ValueError(f"action must have shape ({ACTION_DIM},) = [x, y, z, yaw, gripper], got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite, got {a.tolist()}")
        out = np.clip(a, self.action_space.low, self.action_space.high)
        return out, bool((out != a).any())

    def render(self) -> np.ndarray | None:
        """uint8 (H, W, 3) third-view camera image with ``render_mode="rgb_array"``; None without a render mode."""
        if self.render_mode is None:
            return None
        return self.render_camera(RENDER_CAMERA)

    def close(self) -> None:
        """Free the renderer (the GL context) and the tactile worker threads."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    # ------------------------------------------------------------------ state
    @property
    def home_tcp(self) -> np.ndarray:
        """float64 (4,) where the hand starts: the "home" keyframe's [x, y, z, yaw] (m, rad)."""
        return self._home.copy()

    @property
    def command(self) -> np.ndarray:
        """float64 (5,) the target the servos hold now: [x, y, z, yaw, gripper] (the last action)."""
        return self._target.copy()

    def tcp_pose(self) -> np.ndarray:
        """float64 (4,) current TCP [x, y, z, yaw] (m, rad)."""
        return np.array([self.data.qpos[self._jnt[n]] for n in ("hand_x", "hand_y", "hand_z", "hand_yaw")])

    def gripper_closure(self) -> float:
        """Mean finger closure in [0, 1] (0 = fully open)."""
        q = 0.5 * (self.data.qpos[self._jnt["left_finger"]] + self.data.qpos[self._jnt["right_finger"]])
        return float(np.clip((self._finger_open - q) / (self._finger_open - self._finger_closed), 0.0, 1.0))

    def peg_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Peg centre position (3,) m and rotation matrix (3, 3), world frame (privileged)."""
        return self.data.xpos[self._peg_body].copy(), self.data.xmat[self._peg_body].reshape(3, 3).copy()

    def peg_bottom(self) -> np.ndarray:
        """World position (3,) of the centre of the peg's bottom face."""
        pos, rot = self.peg_pose()
        return pos - rot[:, 2] * self.peg_half_length_m

    def peg_offset_in_hand(self) -> float:
        """Offset (m) of the peg's centre from the TCP along the gel: the hand's x axis, the tactile
        images' columns (privileged; ``in_hand_offset_m`` is the offset the episode started with)."""
        q, tcp = self._peg_qpos, self.tcp_pose()
        c, s = math.cos(tcp[3]), math.sin(tcp[3])
        return float(c * (self.data.qpos[q] - tcp[0]) + s * (self.data.qpos[q + 1] - tcp[1]))

    def set_peg_offset_in_hand(self, offset_m: float) -> None:
        """Slide the peg along the gel (the hand's x axis) so its centre is ``offset_m`` off the TCP,
        keeping its height, orientation and position across the gel, and nothing else changed: velocities
        are zeroed and positions, contacts and sensors recomputed (``mj_forward``) without advancing
        time. For probes that render one hand pose with the held peg at several offsets
        (``benchmarks.touch_il.vision_check``). ``in_hand_offset_m`` keeps the episode's drawn value."""
        q, tcp, d = self._peg_qpos, self.tcp_pose(), self.data
        c, s = math.cos(tcp[3]), math.sin(tcp[3])
        across = -s * (d.qpos[q] - tcp[0]) + c * (d.qpos[q + 1] - tcp[1])
        d.qpos[q] = tcp[0] + c * offset_m - s * across
        d.qpos[q + 1] = tcp[1] + s * offset_m + c * across
        d.qvel[:] = 0.0
        with mujoco_warnings() as said:
            mujoco.mj_forward(self.model, d)
        self._check_stable(said, f"at a peg offset of {offset_m * 1000:g} mm")

    def insertion_mm(self) -> float:
        """How far the peg's bottom is below the rim (mm) while it is inside the hole's radius; else 0."""
        bottom = self.peg_bottom()
        if np.linalg.norm(bottom[:2] - self.hole_xy) >= self.config.hole_diameter_mm / 2000.0:
            return 0.0
        return float(max(0.0, (rim_height_m(self.config.hole_depth_mm) - bottom[2]) * 1000.0))

    def is_success(self) -> bool:
        """Peg bottom at least ``success_depth_mm`` below the rim, inside the hole's radius."""
        return self.insertion_mm() >= self.config.success_depth_mm

    def pad_forces(self) -> dict[str, np.ndarray]:
        """float32 (3,) [Fx, Fy, Fz] N on each gel, sensor frame."""
        out = {}
        for s in SENSORS:
            rot = self.data.site_xmat[self._sensor_site[s]].reshape(3, 3)
            out[s] = pad_force(self.model, self.data, self._gel[s], rot).astype(np.float32)
        return out

    def pad_in_contact(self, sensor: str) -> bool:
        """Whether the peg touches the given gel."""
        return self._gel_contacts(sensor)[0]

    def _gel_contacts(self, sensor: str) -> tuple[bool, bool]:
        """(the peg touches the gel, anything else touches it)."""
        g = self.data.contact.geom
        gel = self._gel[sensor]
        other = np.where(g[:, 0] == gel, g[:, 1], np.where(g[:, 1] == gel, g[:, 0], -1))
        other = other[other >= 0]
        return bool((other == self._peg_geom).any()), bool((other != self._peg_geom).any())

    # ------------------------------------------------------------------ rendering
    def render_camera(self, camera: str) -> np.ndarray:
        """uint8 (H, W, 3) RGB image of a configured camera."""
        if self._renderer is None:
            raise ValueError("no cameras configured (PegInHoleConfig.cameras is empty)")
        self._renderer.update_scene(self.data, camera=camera)
        return self._renderer.render()

    def penetration_mm(self, sensor: str) -> np.ndarray:
        """float32 (H, W) penetration into a gel (mm); zeros without contact (no rays cast).

        Rays see the peg when it touches the gel, and the static world (table, receptacle) and the
        other finger only when one of them touches it (rare; it keeps image and force label consistent).
        """
        if sensor not in self._rays:
            raise ValueError(f"tactile is off or unknown sensor {sensor!r}; expected one of {SENSORS}")
        peg, other = self._gel_contacts(sensor)
        pen = np.zeros(self.config.tactile_size, np.float32)
        if peg:
            pen = self._rays[sensor].penetration_mm(PEG_RAYS)
        if other:
            world = self._rays[sensor].penetration_mm(WORLD_RAYS, include_static=True,
                                                      exclude_body=self._finger_body[sensor])
            np.maximum(pen, world, out=pen)
        return pen

    def render_tactile(self, sensor: str, force: np.ndarray | None = None) -> np.ndarray:
        """uint8 (H, W, 3) tactile image of one finger (sensor model optics over its background)."""
        pen = self.penetration_mm(sensor)
        if force is None:
            force = self.pad_forces()[sensor]
        shear = (float(force[0]), float(force[1])) if pen.any() else (0.0, 0.0)
        return self._sensors[sensor].render_penetration(pen, shear=shear, noise_seed=self._noise_seed(sensor))

    def tactile_sensor(self, sensor: str):
        """The ``TactileSensor`` (sensor model) rendering one finger's images."""
        if sensor not in self._sensors:
            raise ValueError(f"tactile is off or unknown sensor {sensor!r}; expected one of {SENSORS}")
        return self._sensors[sensor]

    def pad_rays(self, sensor: str) -> PadRays:
        """The ray caster of one finger's gel."""
        if sensor not in self._rays:
            raise ValueError(f"tactile is off or unknown sensor {sensor!r}; expected one of {SENSORS}")
        return self._rays[sensor]

    def tactile_background(self, sensor: str) -> np.ndarray:
        """uint8 (H, W, 3) no-contact image of a sensor (zero penetration rendered without noise)."""
        if sensor not in self._backgrounds:
            raise ValueError(f"tactile is off or unknown sensor {sensor!r}; expected one of {SENSORS}")
        return self._backgrounds[sensor].copy()

    def _noise_seed(self, sensor: str) -> int | None:
        if not self.config.tactile_noise:
            return None
        return (self._episode_seed * 1_000_003 + self._steps * 7 + SENSORS.index(sensor)) % (2**63)

    # ------------------------------------------------------------------ internals
    def _observe(self) -> dict:
        """Observation of the current state. The tactile optics of both pads run in worker threads
        while the cameras render (ray casting, forces and GL stay on this thread: they use mjData)."""
        obs = {LOOP_STATE: np.array([*self.tcp_pose(), self.gripper_closure()], dtype=np.float32)}
        forces = self.pad_forces()
        pending = {}
        if self.config.tactile:
            for s in SENSORS:
                pen = self.penetration_mm(s)
                shear = (float(forces[s][0]), float(forces[s][1])) if pen.any() else (0.0, 0.0)
                pending[s] = self._pool.submit(self._sensors[s].render_penetration, pen, shear, self._noise_seed(s))
        for cam in self.config.cameras:
            obs[image_key(cam, LOOP)] = self.render_camera(cam)
        for s in SENSORS:
            if s in pending:
                obs[tactile_key(s, LOOP)] = pending[s].result()
            obs[force_key(s, LOOP)] = forces[s]
        return obs

    def _ctrl_vector(self, target: np.ndarray) -> np.ndarray:
        """Actuator controls (nu,) for an action [x, y, z, yaw, gripper]."""
        ctrl = np.empty(self.model.nu)
        ctrl[self._pose_act] = target[:POSE_DIM]
        ctrl[self._finger_act] = self._finger_open - target[GRIPPER] * (self._finger_open - self._finger_closed)
        return ctrl

    def _peg_static_penetration(self) -> float:
        """Deepest penetration (m) of the peg into the table or receptacle (contact sensors; 0 = none)."""
        sd = self.data.sensordata
        return -min(sd[self._contact_dist[0]], sd[self._contact_dist[1]], 0.0)

    def _check_stable(self, said: list[str], where: str) -> None:
        """RuntimeError naming ``where`` and MuJoCo's words if it warned (``said``, or any warning counted since
        the episode's keyframe reset zeroed the counters: a settle that warned raises) or the state is not finite."""
        d = self.data
        if not said and np.isfinite(d.qpos).all() and not d.warning.number.any():
            return
        named = ", ".join(f"{mujoco.mjtWarning(i).name} x{w.number}" for i, w in enumerate(d.warning) if w.number)
        raise RuntimeError(f"simulation became unstable {where} (MuJoCo: "
                           f"{' / '.join(said) or named or 'a state that is not finite'})")


@contextmanager
def mujoco_warnings():
    """Collect MuJoCo's warning messages in a list instead of its default handling (a line on stdout and
    MUJOCO_LOG.TXT written into the working directory); the previous handler is restored on exit. MuJoCo's handler
    is process-global: one thread steps MuJoCo at a time."""
    said: list[str] = []
    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(said.append)
    try:
        yield said
    finally:
        mujoco.set_mju_user_warning(before)


# gymnasium.make("envs.peg_in_hole:PegInHole-v0", config=..., render_mode=...) imports this module and
# builds the env (episodes end by the env's own success / max_steps, so no TimeLimit is added)
gym.register(id="PegInHole-v0", entry_point="envs.peg_in_hole:PegInHoleEnv")
