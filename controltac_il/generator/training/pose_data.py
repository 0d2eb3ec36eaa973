"""Training and evaluation data of the stage-2 pose adapter: sensor-model scenes and cross-pose pairs.

A scene is one object on one simulated sensor instance, pressed at ``poses`` random contact poses with
``forces`` random forces each. Pairs are formed within a scene (reference and target may differ in pose
and force); the condition is the reference's geometric contact mask moved rigidly to the target pose
(``tactile.pose.transform_between``), which is what a user can compute from a reference image and a
desired pose change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm
from controltac_il.cli import tty_only

from controltac_il.generator.config import FZ_RANGE, SHEAR_MAX
from controltac_il.tactile import SensorSpec, TactileSensor
from controltac_il.tactile.indenters import get_indenter
from controltac_il.tactile.instances import sensor_instance
from controltac_il.tactile.pose import move_mask, transform_between

MIN_CONTACT_PX = 40  # a pose whose contact covers fewer pixels (mostly off the pad) is drawn again
POSE_SPREAD = 0.6  # object origins lie within this fraction of the pad's half-size from its centre


@dataclass
class PoseScenes:
    """Rendered scenes. residuals: uint8 (N, H, W, 3); masks: bool (N, H, W) geometric contact; poses: float64
    (N, 3) (x_mm, y_mm, theta_rad); forces: float32 (N, 3) N; scene: int64 (N,) scene index; objects: the
    object of each scene; backgrounds: uint8 (S, H, W, 3) each scene's no-contact frame; mm_per_px: pixel
    pitch of the images."""

    residuals: np.ndarray
    masks: np.ndarray
    poses: np.ndarray
    forces: np.ndarray
    scene: np.ndarray
    objects: list[str]
    backgrounds: np.ndarray
    mm_per_px: float

    def members(self) -> list[np.ndarray]:
        """Frame indices of each scene."""
        order = np.argsort(self.scene, kind="stable")
        return np.split(order, np.flatnonzero(np.diff(self.scene[order])) + 1)


def render_scenes(objects: Sequence[str], scenes_per_object: int, poses: int, forces: int, seed: int,
                  size: tuple[int, int] = (120, 160), family: str | None = "train", instances: int = 16,
                  progress: bool = True) -> PoseScenes:
    """Render ``scenes_per_object`` scenes of each object, each on one sensor instance of ``family`` (drawn among
    its first ``instances``; None: the nominal GelSight Mini) with ``poses`` x ``forces`` frames. Forces: Fz
    U[validated range], shear U[±SHEAR_MAX]; poses: origin within ``POSE_SPREAD`` of the half-pad, theta U[0, π).
    A pure function of the arguments."""
    for name in objects:
        get_indenter(name)
    sensors: dict[int, TactileSensor] = {}
    res, masks, pose_rows, force_rows, scene_rows, scene_objects, bgs = [], [], [], [], [], [], []
    total = len(objects) * scenes_per_object * poses * forces
    with tqdm(total=total, desc="rendering pose scenes", unit="img", disable=tty_only(progress)) as bar:
        for oi, name in enumerate(objects):
            for si in range(scenes_per_object):
                rng = np.random.default_rng([seed, oi, si])
                which = int(rng.integers(instances)) if family is not None else -1
                if which not in sensors:
                    inst = sensor_instance(family, which, size) if family is not None else None
                    sensors[which] = (TactileSensor(inst.spec, optics=inst.optics) if inst is not None
                                      else TactileSensor(SensorSpec.gelsight_mini().scaled(*size)))
                sensor = sensors[which]
                half_h, half_w = (s / 2 for s in sensor.spec.pad_size_mm)
                scene_id = len(scene_objects)
                scene_objects.append(name)
                bgs.append(sensor.background)
                for _ in range(poses):
                    for _attempt in range(20):
                        pose = (rng.uniform(-POSE_SPREAD, POSE_SPREAD) * half_w,
                                rng.uniform(-POSE_SPREAD, POSE_SPREAD) * half_h, rng.uniform(0, np.pi))
                        if get_indenter(name).heightmap(sensor.spec, pose).max() > 0 or _attempt == 19:
                            break
                    for _ in range(forces):
                        force = (*rng.uniform(-SHEAR_MAX, SHEAR_MAX, 2), rng.uniform(*FZ_RANGE))
                        c = sensor.press(name, pose, force, noise_seed=int(rng.integers(2**31)))
                        bar.update()
                        if c.mask.sum() < MIN_CONTACT_PX:
                            continue
                        res.append(c.residual)
                        masks.append(c.mask)
                        pose_rows.append(pose)
                        force_rows.append(c.force)
                        scene_rows.append(scene_id)
    return PoseScenes(np.stack(res), np.stack(masks), np.asarray(pose_rows, np.float64),
                      np.asarray(force_rows, np.float32), np.asarray(scene_rows, np.int64), scene_objects,
                      np.stack(bgs), float(sensors[next(iter(sensors))].spec.mm_per_px))


def target_mask(scenes: PoseScenes, ref: int, tgt: int, noise: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """The reference's contact mask carried to the target's pose, plus ``noise`` = (dx_px, dy_px, dtheta rad)
    of misalignment; bool (H, W). Where the move would leave nothing on the pad, the target's own mask."""
    t = transform_between(scenes.poses[ref], scenes.poses[tgt], scenes.masks[ref], scenes.mm_per_px)
    try:
        return move_mask(scenes.masks[ref], np.add(t, noise))
    except ValueError:
        return scenes.masks[tgt]


def sample_pose_pairs(scenes: PoseScenes, members: list[np.ndarray], batch: int, rng: np.random.Generator,
                      alignment_px: float, alignment_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ref_idx, tgt_idx, ΔF float32 (batch, 3) N, masks bool (batch, H, W)): pairs within random scenes, masks
    with uniform alignment noise of ±alignment_px and ±alignment_deg."""
    ref = np.empty(batch, np.int64)
    tgt = np.empty(batch, np.int64)
    masks = np.empty((batch, *scenes.masks.shape[1:]), bool)
    for k, s in enumerate(rng.integers(0, len(members), size=batch)):
        ref[k], tgt[k] = rng.choice(members[s], size=2)
        noise = (*rng.uniform(-alignment_px, alignment_px, 2), np.radians(rng.uniform(-alignment_deg, alignment_deg)))
        masks[k] = target_mask(scenes, ref[k], tgt[k], noise)
    return ref, tgt, (scenes.forces[tgt] - scenes.forces[ref]).astype(np.float32), masks
