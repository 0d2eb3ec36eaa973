"""Stage-1 training data of the generator: sensor-model residuals at the model size, pose groups, force pairs.

Pairs are formed between images of the same contact pose (the paper's rule): reference i and target
j of one (object, pose_id) group, ΔF = F_j - F_i. A small share of pairs are no-contact frames
(the bare sensor with fresh noise) with a random ΔF: a reference without contact must stay without
contact whatever force is asked for.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm.auto import tqdm
from controltac_il.cli import tty_only

from controltac_il.generator.config import FZ_RANGE, SHEAR_MAX
from controltac_il.generator.pipeline import residual_to_unit
from controltac_il.tactile.residual import contact_mask

# ΔF range of the random no-contact pairs, per component (N): the validated range's span.
NO_CONTACT_DELTA = np.array([2 * SHEAR_MAX, 2 * SHEAR_MAX, FZ_RANGE[1] - FZ_RANGE[0]], dtype=np.float32)


@dataclass
class PairData:
    """residuals: uint8 (N, H, W, 3) at the model size; forces: float32 (N, 3) N;
    groups: index arrays of images sharing a contact pose; no_contact: indices of no-contact frames;
    group_objects: the object each group presses ("" where unknown). ``images``: the indices training
    draws from (the groups' and the no-contact frames; a held-out group's frames are not among them)."""

    residuals: np.ndarray
    forces: np.ndarray
    groups: list[np.ndarray]
    no_contact: np.ndarray
    group_objects: list[str] = field(default_factory=list)

    def __post_init__(self):
        if self.residuals.dtype != np.uint8 or self.residuals.ndim != 4 or self.residuals.shape[-1] != 3:
            raise ValueError(f"residuals must be uint8 (N, H, W, 3), got {self.residuals.dtype} {self.residuals.shape}")
        if self.forces.shape != (len(self.residuals), 3):
            raise ValueError(f"forces must be ({len(self.residuals)}, 3), got {self.forces.shape}")
        if not self.groups:
            raise ValueError("at least one pose group is needed to form pairs")
        if not self.group_objects:
            self.group_objects = [""] * len(self.groups)
        if len(self.group_objects) != len(self.groups):
            raise ValueError(f"group_objects must name {len(self.groups)} groups, got {len(self.group_objects)}")
        self.images = np.concatenate([*self.groups, self.no_contact]).astype(np.int64)


def resize_residual(residual: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize a uint8 residual (H, W, 3) to ``size`` = (H, W) (area when shrinking, linear when growing)."""
    h, w = size
    if residual.shape[:2] == (h, w):
        return residual
    shrink = residual.shape[0] > h or residual.shape[1] > w
    return cv2.resize(residual, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def no_contact_residuals(meta: dict, count: int, seed: int) -> np.ndarray:
    """``count`` residuals of the bare sensor (the dataset's spec and optics) with fresh noise, uint8."""
    from controltac_il.tactile import SensorSpec, TactileSensor, to_residual
    from controltac_il.tactile.instances import instance_by_name

    spec = SensorSpec(**meta["spec"]) if "spec" in meta else SensorSpec.gelsight_mini()
    if meta.get("sensor_names"):  # sensor randomisation: the bare frames cycle through the dataset's instances
        sensors = [TactileSensor(i.spec, optics=i.optics) for i in
                   (instance_by_name(n, (spec.height, spec.width)) for n in meta["sensor_names"])]
    else:
        sensors = [TactileSensor(spec, optics=meta.get("optics", "three_light"))]
    zero = np.zeros((spec.height, spec.width), np.float32)
    rng = np.random.default_rng([seed, 7919])
    out = []
    for j, s in enumerate(rng.integers(0, 2**31, size=count)):
        sensor = sensors[j % len(sensors)]
        out.append(to_residual(sensor.render_penetration(zero, noise_seed=int(s)), sensor.background))
    return np.stack(out)


def load_pair_data(root: str | Path, image_size: tuple[int, int], no_contact_frames: int = 32, seed: int = 0,
                   progress: bool = True) -> PairData:
    """Read a ``write_dataset`` folder into memory at ``image_size`` plus ``no_contact_frames`` bare frames."""
    from controltac_il.tactile.dataset import load_dataset

    ds = load_dataset(root)
    res = [resize_residual(ds.residual(i), image_size)
           for i in tqdm(range(len(ds)), desc="loading residuals", unit="img", disable=tty_only(progress))]
    forces = ds.forces()
    pose_groups = ds.pose_groups()
    groups = [np.asarray(g, dtype=np.int64) for g in pose_groups.values()]
    nc = np.zeros((0,), np.int64)
    if no_contact_frames > 0:
        extra = [resize_residual(r, image_size) for r in no_contact_residuals(ds.meta, no_contact_frames, seed)]
        nc = np.arange(len(res), len(res) + len(extra))
        res.extend(extra)
        forces = np.concatenate([forces, np.zeros((len(extra), 3), np.float32)])
    return PairData(np.stack(res), forces.astype(np.float32), groups, nc, [obj for obj, _ in pose_groups])


def sample_pairs(data: PairData, batch: int, rng: np.random.Generator, no_contact_prob: float = 0.05,
                 distinct: bool = False, increase_prob: float = 0.0):
    """(ref_idx, tgt_idx, delta_force float32 (batch, 3)): pairs within a random pose group (``distinct``: two
    different frames wherever the group has two); with probability ``increase_prob`` a pair is ordered so that the
    target presses harder (ΔFz >= 0: the direction most ForceAugment targets take); with probability
    ``no_contact_prob`` a no-contact pair with a random ΔF instead. ``increase_prob`` 0 draws nothing extra (the
    same pairs as without it)."""
    gi = rng.integers(0, len(data.groups), size=batch)
    ref = np.empty(batch, np.int64)
    tgt = np.empty(batch, np.int64)
    for k, g in enumerate(gi):
        members = data.groups[g]
        i, j = rng.integers(0, len(members), size=2)
        if distinct and len(members) > 1 and i == j:
            j = (i + rng.integers(1, len(members))) % len(members)
        ref[k], tgt[k] = members[i], members[j]
    if increase_prob > 0:
        swap = (rng.random(batch) < increase_prob) & (data.forces[tgt, 2] < data.forces[ref, 2])
        ref[swap], tgt[swap] = tgt[swap], ref[swap].copy()
    delta = data.forces[tgt] - data.forces[ref]
    if len(data.no_contact) and no_contact_prob > 0:
        nc = rng.random(batch) < no_contact_prob
        m = int(nc.sum())
        if m:
            ref[nc] = rng.choice(data.no_contact, size=m)
            tgt[nc] = rng.choice(data.no_contact, size=m)
            delta[nc] = rng.uniform(-1, 1, size=(m, 3)).astype(np.float32) * NO_CONTACT_DELTA
    return ref, tgt, delta.astype(np.float32)


def new_contact(data: PairData, ref: np.ndarray, tgt: np.ndarray, factor: int) -> np.ndarray:
    """float32 (B, 1, H / factor, W / factor): 1 where the target's contact (``contact_mask``) reaches beyond the
    reference's in a factor × factor cell (the new contact a harder press shows), else 0."""
    new = contact_mask(data.residuals[tgt]) & ~contact_mask(data.residuals[ref])
    b, h, w = new.shape
    cells = new[:, :h - h % factor, :w - w % factor].reshape(b, h // factor, factor, w // factor, factor)
    return cells.any(axis=(2, 4))[:, None].astype(np.float32)


def crop_batch(data: PairData, rng: np.random.Generator, batch: int, crop: tuple[int, int]) -> torch.Tensor:
    """Random crops (with random flips) of random training residuals (``data.images``), float (B, 3, ch, cw)
    in [-1, 1]; half of them centred on a contact pixel."""
    idx = data.images[rng.integers(0, len(data.images), size=batch)]
    H, W = data.residuals.shape[1:3]
    ch, cw = crop
    out = np.empty((batch, ch, cw, 3), np.uint8)
    for k, i in enumerate(idx):
        y, x = rng.integers(0, H - ch + 1), rng.integers(0, W - cw + 1)
        if rng.random() < 0.5:  # half the crops centred on a contact pixel (contacts cover little of the pad)
            ys, xs = np.nonzero(contact_mask(data.residuals[i], threshold=12.0))
            if len(ys):
                j = rng.integers(0, len(ys))
                y = int(np.clip(ys[j] - ch // 2, 0, H - ch))
                x = int(np.clip(xs[j] - cw // 2, 0, W - cw))
        c = data.residuals[i, y:y + ch, x:x + cw]
        if rng.random() < 0.5:
            c = c[:, ::-1]
        if rng.random() < 0.5:
            c = c[::-1]
        out[k] = c
    return residual_to_unit(torch.from_numpy(out))
