"""Penetration maps of the peg into each gel, by ray casting from a pinhole behind the gel.

For every pixel of the sensor a ray goes from a pinhole ``pinhole_depth_mm`` behind the gel
surface (inside the finger) through the pixel's point on the undeformed gel surface. The rays see
only the geom groups asked for (``mj_multiRay``'s group mask: the peg's group, or the static world's
when the gel touches it). With ``s`` the distance from the pinhole to the surface along the ray and
``h`` the distance to the hit, the object lies ``(s - h) * D / s`` mm inside the gel along the
surface normal (``D`` the pinhole depth): the penetration map the sensor model's optics turn into
an image.

Sensor frame (MJCF sites ``<name>_sensor``, origin at the gel surface centre): x along image
columns (right), y up the image rows, z into the sensor.
"""

from __future__ import annotations

import cv2
import numpy as np

from controltac_il.extras import require

mujoco = require("mujoco", "sim", "the MuJoCo scene")

MISS_MM = -10.0  # gap assigned to a ray that hits nothing (far outside the gel)


def group_mask(*groups: int) -> np.ndarray:
    """``mj_multiRay`` geom-group mask (6,) uint8 that lets rays see only ``groups``."""
    mask = np.zeros(6, np.uint8)
    mask[list(groups)] = 1
    return mask


class PadRays:
    """Ray caster for one gel pad.

    model, data: the MuJoCo model and its data (read at call time).
    site: name of the pad's sensor-frame site.
    size: (H, W) of the penetration map in pixels.
    pad_mm: (height, width) of the gel's sensing area in mm.
    stride: rays every ``stride`` pixels; the gap is upsampled bilinearly.
    pinhole_depth_mm: distance of the pinhole behind the gel surface.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, site: str,
                 size: tuple[int, int], pad_mm: tuple[float, float], stride: int = 2,
                 pinhole_depth_mm: float = 20.0):
        self.model, self.data = model, data
        self.site_id = model.site(site).id
        self.size = (int(size[0]), int(size[1]))
        h, w = self.size
        self.stride = int(stride)
        hc, wc = -(-h // self.stride), -(-w // self.stride)  # ceil: the coarse grid covers the pad
        pitch_y, pitch_x = pad_mm[0] / h, pad_mm[1] / w
        # coarse pixel centres in fine-pixel units (matches cv2's half-pixel bilinear resize)
        cols = (np.arange(wc) * self.stride + self.stride / 2.0 - w / 2.0) * pitch_x
        rows = (h / 2.0 - np.arange(hc) * self.stride - self.stride / 2.0) * pitch_y
        u, v = np.meshgrid(cols, rows)
        self.depth_mm = float(pinhole_depth_mm)
        local = np.stack([u, v, np.full_like(u, -self.depth_mm)], axis=-1).reshape(-1, 3)
        self._surface_mm = np.linalg.norm(local, axis=1)  # pinhole -> undeformed surface, per ray
        self._dirs_local = local / self._surface_mm[:, None]
        self._coarse = (hc, wc)
        n = hc * wc
        self._geomid = np.zeros(n, np.int32)
        self._dist = np.zeros(n, np.float64)
        self._vec = np.zeros((n, 3), np.float64)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) world-from-sensor rotation of the pad."""
        return self.data.site_xmat[self.site_id].reshape(3, 3)

    def penetration_mm(self, groups: np.ndarray, include_static: bool = False, exclude_body: int = -1) -> np.ndarray:
        """float32 (H, W) depth of what the rays hit inside the gel, along its normal (mm, >= 0).

        groups: ``group_mask(...)`` of the geom groups the rays see. include_static: also hit geoms of
        static bodies (table, receptacle). exclude_body: a body the rays pass through (the finger).
        """
        rot = self.rotation
        origin = self.data.site_xpos[self.site_id] + rot[:, 2] * (self.depth_mm / 1000.0)
        np.matmul(self._dirs_local, rot.T, out=self._vec)
        n = self._vec.shape[0]
        cutoff = (self._surface_mm.max() + 5.0) / 1000.0
        mujoco.mj_multiRay(self.model, self.data, origin, self._vec.reshape(-1), groups, include_static,
                           exclude_body, self._geomid, self._dist, None, n, cutoff)
        hit = self._geomid >= 0
        gap = np.where(hit, (self._surface_mm - self._dist * 1000.0) * self.depth_mm / self._surface_mm, MISS_MM)
        gap = gap.reshape(self._coarse).astype(np.float32)
        h, w = self.size
        if self.stride > 1:
            gap = cv2.resize(gap, (gap.shape[1] * self.stride, gap.shape[0] * self.stride),
                             interpolation=cv2.INTER_LINEAR)[:h, :w]
        return np.maximum(gap, 0.0, out=np.ascontiguousarray(gap))


def pad_force(model: mujoco.MjModel, data: mujoco.MjData, gel_geom: int, rotation: np.ndarray) -> np.ndarray:
    """float64 (3,) force the touching bodies exert on the gel, [Fx, Fy, Fz] N in the sensor frame.

    Sums ``mj_contactForce`` over the gel's active contacts; Fz > 0 when the gel is pressed.
    """
    total = np.zeros(3)
    f6 = np.zeros(6)
    con = data.contact
    active = ((con.geom[:, 0] == gel_geom) | (con.geom[:, 1] == gel_geom)) & (con.efc_address >= 0)
    for i in np.flatnonzero(active):
        c = data.contact[i]
        mujoco.mj_contactForce(model, data, int(i), f6)
        world = c.frame.reshape(3, 3).T @ f6[:3]  # force on geom2, world frame
        total += world if c.geom2 == gel_geom else -world
    return rotation.T @ total
