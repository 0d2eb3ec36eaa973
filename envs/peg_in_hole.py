"""``PegInHoleEnv``: Gymnasium-style MuJoCo peg-in-hole scene with tactile fingers.

Action (5,): absolute end-effector target [x, y, z, yaw] (m, rad; TCP between the gel centres,
world frame) and a gripper command in [0, 1] (0 = open, 1 = closed): the action space of the robot
adapters. Within one control step the servo target moves linearly from the previous target to the
new one (the robot's own interpolation), then holds.

Observation dict:
    qpos            float32 (5,): TCP [x, y, z, yaw] and gripper closure in [0, 1]
    images/<cam>    uint8 (H, W, 3) for each configured camera
    tactile/<s>     uint8 (H, W, 3) for s in ("left", "right") when ``config.tactile``
    force/<s>       float32 (3,): [Fx, Fy, Fz] N on each gel in its sensor frame (Fz > 0 pressing)
"""

from __future__ import annotations

import dataclasses
import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the first mujoco import
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
import mujoco  # noqa: E402

from envs.config import SENSORS, PegInHoleConfig  # noqa: E402
from envs.scene import build_model, rim_height_m  # noqa: E402
from envs.tactile_rig import PadRays, group_mask, pad_force  # noqa: E402

PEG_RADIUS_M = 0.0125
PEG_HALF_LENGTH_M = 0.04
FINGER_OPEN_M = 0.03  # gel surface distance from the TCP plane, gripper command 0
FINGER_CLOSED_M = 0.004  # servo target at command 1 (inside the peg: the grip force saturates)
PEG_RAYS = group_mask(1)  # the peg's geom group
WORLD_RAYS = group_mask(0, 3)  # table, hole floor, gripper (0) and the receptacle's collision walls (3)
HOME = (0.0, 0.0, 0.15, 0.0)


class PegInHoleEnv:
    """MuJoCo peg-in-hole scene. See the module docstring for the action and observation spaces.

    Episode randomisation (seeded by ``reset(seed=...)``): peg position and yaw, hole position,
    grip force (``config.grip_force_range_n``); the in-hand offset comes from where the policy
    grasps, or, with ``config.peg_in_hand``, is drawn (``in_hand_offset_m``, privileged). ``info`` holds ``success``, ``clipped`` (the target was outside the workspace or the
    gripper command outside [0, 1]), ``grip_force_n``, ``insertion_mm`` and ``max_penetration_mm``
    (deepest peg contact with the receptacle or table).
    """

    action_dim = 5
    qpos_dim = 5

    def __init__(self, config: PegInHoleConfig | None = None):
        self.config = config or PegInHoleConfig()
        cfg = self.config
        self.model = build_model(cfg.hole_diameter_mm, cfg.hole_depth_mm, cfg.ring_segments, cfg.camera_size,
                                 cfg.hole_chamfer_mm, cfg.camera_layout)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._jnt = {n: m.joint(n).qposadr[0] for n in
                     ("hand_x", "hand_y", "hand_z", "hand_yaw", "left_finger", "right_finger")}
        self._act = {m.actuator(i).name: i for i in range(m.nu)}
        self._peg_body = m.body("peg").id
        self._peg_qpos = m.joint("peg").qposadr[0]
        self._peg_geom = m.geom("peg").id
        self._receptacle = m.body("receptacle").id
        self._gel = {s: m.geom(f"{s}_gel").id for s in SENSORS}
        self._sensor_site = {s: m.site(f"{s}_sensor").id for s in SENSORS}
        self._finger_body = {s: m.body(f"{s}_finger").id for s in SENSORS}
        # contact sensors (MJCF): [found, dist] of the peg's deepest contact with receptacle / table
        self._contact_dist = [m.sensor_adr[m.sensor(n).id] + 1 for n in ("peg_receptacle", "peg_table")]
        self._pose_act = [self._act[n] for n in ("hand_x", "hand_y", "hand_z", "hand_yaw")]
        self._finger_act = [self._act[f"{s}_finger"] for s in SENSORS]
        self._low = np.array(cfg.workspace_low)
        self._high = np.array(cfg.workspace_high)
        self._renderer = None
        if cfg.cameras:
            self._renderer = mujoco.Renderer(m, cfg.camera_size[0], cfg.camera_size[1])
        self._sensors: dict = {}
        self._rays: dict[str, PadRays] = {}
        self._backgrounds: dict[str, np.ndarray] = {}
        if cfg.tactile:
            from controltac_il.tactile import SensorSpec, TactileSensor

            spec = SensorSpec.gelsight_mini().scaled(*cfg.tactile_size)
            flat = np.zeros(cfg.tactile_size, np.float32)
            quiet_spec = dataclasses.replace(spec, noise_std=0.0)
            for k, s in enumerate(SENSORS):
                quiet = TactileSensor(quiet_spec, optics=cfg.tactile_optics)
                self._sensors[s] = TactileSensor(spec, optics=cfg.tactile_optics, seed=k) if cfg.tactile_noise else quiet
                self._rays[s] = PadRays(m, self.data, f"{s}_sensor", cfg.tactile_size, spec.pad_size_mm,
                                        cfg.ray_stride)
                # no-contact frame = the optics over a flat gel without noise (the optics' flat-gel
                # response is not exactly the raw background for every optics model)
                self._backgrounds[s] = quiet.render_penetration(flat)
        self._pool = ThreadPoolExecutor(len(SENSORS), thread_name_prefix="tactile") if cfg.tactile else None
        self._rng = np.random.default_rng()
        self._episode_seed = 0
        self.hole_xy = np.zeros(2)
        self.grip_force_n = 0.0
        self.in_hand_offset_m: float | None = None
        self._target = np.array([*HOME, 0.0])
        self._steps = 0
        self._warnings = 0

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        """Start an episode; returns (observation, info). ``seed`` fixes every random draw."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
            self._episode_seed = int(seed)
        else:
            self._episode_seed = int(self._rng.integers(2**31))
        cfg, m, d = self.config, self.model, self.data
        rng = self._rng
        peg_xy = np.array([rng.uniform(*cfg.peg_xy_range_m[0]), rng.uniform(*cfg.peg_xy_range_m[1])])
        peg_yaw = rng.uniform(*cfg.peg_yaw_range_rad)
        self.hole_xy = np.array([rng.uniform(*cfg.hole_xy_range_m[0]), rng.uniform(*cfg.hole_xy_range_m[1])])
        self.grip_force_n = float(rng.uniform(*cfg.grip_force_range_n))
        mujoco.mj_resetData(m, d)
        m.body_pos[self._receptacle] = [*self.hole_xy, 0.0]
        for s in SENSORS:
            m.actuator_forcerange[self._act[f"{s}_finger"]] = [-self.grip_force_n, self.grip_force_n]
        q = self._peg_qpos
        d.qpos[q + 3:q + 7] = [math.cos(peg_yaw / 2), 0.0, 0.0, math.sin(peg_yaw / 2)]
        if cfg.peg_in_hand:
            # hand over the start point, peg between the closed fingers, its axis off the TCP along the gel
            self.in_hand_offset_m = float(rng.choice((-1.0, 1.0)) * rng.uniform(*cfg.in_hand_offset_mm)) / 1000.0
            home = (*peg_xy, HOME[2], 0.0)
            top = HOME[2] + cfg.grasp_depth_mm / 1000.0
            d.qpos[q:q + 3] = [peg_xy[0] + self.in_hand_offset_m, peg_xy[1], top - PEG_HALF_LENGTH_M]
            fingers, closing = PEG_RADIUS_M, 1.0
        else:
            self.in_hand_offset_m = None
            home = HOME
            d.qpos[q:q + 3] = [*peg_xy, PEG_HALF_LENGTH_M]
            fingers, closing = FINGER_OPEN_M, 0.0
        for name, value in zip(("hand_x", "hand_y", "hand_z", "hand_yaw"), home):
            d.qpos[self._jnt[name]] = value
        d.qpos[self._jnt["left_finger"]] = d.qpos[self._jnt["right_finger"]] = fingers
        self._target = np.array([*home, closing])
        d.ctrl[:] = self._ctrl_vector(self._target)
        mujoco.mj_forward(m, d)
        for _ in range(cfg.substeps):  # let the peg settle on the table or in the grip
            mujoco.mj_step(m, d)
        self._steps = 0
        self._warnings = self._warning_count()
        info = {"success": False, "clipped": False, "grip_force_n": self.grip_force_n,
                "insertion_mm": self.insertion_mm(), "max_penetration_mm": 0.0, "episode_seed": self._episode_seed}
        if cfg.peg_in_hand:
            info["in_hand_offset_mm"] = self.in_hand_offset_m * 1000.0
        return self._observe(), info

    def step(self, action) -> tuple[dict, float, bool, bool, dict]:
        """Apply one control step; returns (observation, reward, terminated, truncated, info).

        Raises ValueError on an action that is not 5 finite numbers. Targets outside the workspace
        and gripper commands outside [0, 1] are clipped and flagged in ``info["clipped"]``.
        """
        target, clipped = self.check_action(action)
        m, d = self.model, self.data
        n = self.config.substeps
        # the servo targets are affine in the action, so interpolating controls interpolates targets
        c0, c1 = self._ctrl_vector(self._target), self._ctrl_vector(target)
        ctrls = c0 + (c1 - c0) * (np.arange(1, n + 1) / n)[:, None]
        max_pen = 0.0
        for k in range(n):
            d.ctrl[:] = ctrls[k]
            mujoco.mj_step(m, d)
            max_pen = max(max_pen, self._peg_static_penetration())
        self._target = target
        self._steps += 1
        if not np.isfinite(d.qpos).all() or self._warning_count() > self._warnings:
            raise RuntimeError(f"simulation became unstable at step {self._steps} (MuJoCo warnings: "
                               f"{[(w.number, w.lastinfo) for w in d.warning if w.number]})")
        success = self.is_success()
        info = {"success": success, "clipped": clipped, "grip_force_n": self.grip_force_n,
                "insertion_mm": self.insertion_mm(), "max_penetration_mm": max_pen * 1000.0,
                "episode_seed": self._episode_seed}
        truncated = self._steps >= self.config.max_steps and not success
        return self._observe(), float(success), success, truncated, info

    def check_action(self, action) -> tuple[np.ndarray, bool]:
        """Validate an action; returns (clipped float64 (5,), whether anything was clipped)."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be 5 numbers [x, y, z, yaw, gripper], got {action!r}") from None
        if a.shape != (self.action_dim,):
            raise ValueError(f"action must have shape (5,) = [x, y, z, yaw, gripper], got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite, got {a.tolist()}")
        out = a.copy()
        out[:4] = np.clip(a[:4], self._low, self._high)
        out[4] = min(max(a[4], 0.0), 1.0)
        return out, bool((out != a).any())

    def close(self) -> None:
        """Free the renderer (the GL context) and the tactile worker threads."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ state
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
        return float(np.clip((FINGER_OPEN_M - q) / (FINGER_OPEN_M - FINGER_CLOSED_M), 0.0, 1.0))

    def peg_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Peg centre position (3,) m and rotation matrix (3, 3), world frame (privileged)."""
        return self.data.xpos[self._peg_body].copy(), self.data.xmat[self._peg_body].reshape(3, 3).copy()

    def peg_bottom(self) -> np.ndarray:
        """World position (3,) of the centre of the peg's bottom face."""
        pos, rot = self.peg_pose()
        return pos - rot[:, 2] * PEG_HALF_LENGTH_M

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
        obs = {"qpos": np.array([*self.tcp_pose(), self.gripper_closure()], dtype=np.float32)}
        forces = self.pad_forces()
        pending = {}
        if self.config.tactile:
            for s in SENSORS:
                pen = self.penetration_mm(s)
                shear = (float(forces[s][0]), float(forces[s][1])) if pen.any() else (0.0, 0.0)
                pending[s] = self._pool.submit(self._sensors[s].render_penetration, pen, shear, self._noise_seed(s))
        for cam in self.config.cameras:
            obs[f"images/{cam}"] = self.render_camera(cam)
        for s in SENSORS:
            if s in pending:
                obs[f"tactile/{s}"] = pending[s].result()
            obs[f"force/{s}"] = forces[s]
        return obs

    def _ctrl_vector(self, target: np.ndarray) -> np.ndarray:
        """Actuator controls (nu,) for an action [x, y, z, yaw, gripper]."""
        ctrl = np.empty(self.model.nu)
        ctrl[self._pose_act] = target[:4]
        ctrl[self._finger_act] = FINGER_OPEN_M - target[4] * (FINGER_OPEN_M - FINGER_CLOSED_M)
        return ctrl

    def _peg_static_penetration(self) -> float:
        """Deepest penetration (m) of the peg into the table or receptacle (contact sensors; 0 = none)."""
        sd = self.data.sensordata
        return -min(sd[self._contact_dist[0]], sd[self._contact_dist[1]], 0.0)

    def _warning_count(self) -> int:
        return int(self.data.warning.number.sum())
