"""Training arrays for the estimator: residuals + force labels, no-contact frames, pose-wise splits."""

from __future__ import annotations

import numpy as np

from controltac_il.tactile.residual import OFFSET


def estimate_noise_std(residuals: np.ndarray, max_images: int = 64, contact_level: float = 10.0) -> float:
    """RMS deviation from 127 (grey levels) of the pixels within ``contact_level`` of it, over
    residuals (N, H, W, 3).

    Faint contact fringes count too, so on frames with contact this over-estimates the bare
    sensor's noise (sensor model at 128x160: ≈ 2.0 against 0.66); ``native_no_contact`` renders
    faithful no-contact frames instead.
    """
    d = residuals[:: max(1, len(residuals) // max_images)].astype(np.float32) - OFFSET
    d = d[np.abs(d) <= contact_level]
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def pixel_noise_std(residuals: np.ndarray, max_images: int = 64, level: float = 6.0) -> float:
    """Sensor noise (grey levels) from neighbouring-pixel differences of residuals (N, H, W, 3) at
    their native resolution, skipping pixels more than ``level`` from 127 (contact)."""
    r = residuals[:: max(1, len(residuals) // max_images)].astype(np.float32) - OFFSET
    a, b = r[:, :, 1:], r[:, :, :-1]
    keep = (np.abs(a) <= level) & (np.abs(b) <= level)
    d = (a - b)[keep]
    return float(np.sqrt(np.mean(d * d) / 2)) if d.size else 0.0


def native_no_contact(ds, n: int, size: tuple[int, int] | None = None, seed: int = 0) -> np.ndarray:
    """``n`` no-contact residuals uint8 (n, h, w, 3) made at the dataset's own resolution and
    resized to ``size`` the way ``load_arrays`` resizes frames.

    A sensor-model dataset (``meta.json`` with ``spec``) renders the bare sensor with fresh noise;
    another (e.g. a real recording) gets 127 + Gaussian noise of ``pixel_noise_std``.
    """
    import cv2

    if n == 0:
        h, w = size if size is not None else ds.residual(0).shape[:2]
        return np.zeros((0, h, w, 3), np.uint8)
    if "spec" in ds.meta:
        from controltac_il.tactile import SensorSpec, TactileSensor, to_residual

        sensor = TactileSensor(SensorSpec(**ds.meta["spec"]), optics=ds.meta.get("optics", "three_light"))
        blank = np.zeros((sensor.spec.height, sensor.spec.width), np.float32)
        seeds = np.random.default_rng([seed, 104729]).integers(0, 2**31, size=n)
        frames = [to_residual(sensor.render_penetration(blank, noise_seed=int(s)), sensor.background) for s in seeds]
    else:
        sample = np.stack([ds.residual(i) for i in range(0, len(ds), max(1, len(ds) // 16))])
        frames = list(no_contact_residuals(n, *sample.shape[1:3], pixel_noise_std(sample), seed))
    if size is not None:
        frames = [f if f.shape[:2] == tuple(size) else cv2.resize(f, (size[1], size[0]), interpolation=cv2.INTER_AREA)
                  for f in frames]
    return np.stack(frames)


def no_contact_residuals(n: int, height: int, width: int, noise_std: float, seed: int = 0) -> np.ndarray:
    """``n`` residuals uint8 (n, H, W, 3) of frames without contact: 127 + Gaussian noise of ``noise_std``."""
    if n < 0 or not (np.isfinite(noise_std) and noise_std >= 0):  # NaN would give blank frames, inf frames of 0 and 255
        raise ValueError(f"no_contact_residuals needs n >= 0 and noise_std >= 0, got n={n}, noise_std={noise_std}")
    rng = np.random.default_rng(seed)
    noise = rng.normal(OFFSET, noise_std, size=(n, height, width, 3))
    return np.clip(np.rint(noise), 0, 255).astype(np.uint8)


def load_arrays(ds, indices=None, size: tuple[int, int] | None = None, chunk: int = 256,
                progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Residuals uint8 (N, h, w, 3) and forces float32 (N, 3) of a loaded tactile dataset.

    ``ds`` is a ``controltac_il.tactile.dataset.TactileDataset``; ``indices`` selects rows (default
    all); ``size`` = (h, w) resizes each residual (area-averaged) to save memory.
    """
    import cv2
    from tqdm.auto import tqdm
    from controltac_il.cli import tty_only

    indices = list(range(len(ds))) if indices is None else list(indices)
    if not indices:
        raise ValueError("load_arrays: no rows selected")
    forces = np.asarray([ds.records[i].force for i in indices], dtype=np.float32)
    out = []
    for i in tqdm(indices, desc="loading residuals", disable=tty_only(progress), unit="img"):
        r = ds.residual(i)
        if size is not None and r.shape[:2] != tuple(size):
            r = cv2.resize(r, (size[1], size[0]), interpolation=cv2.INTER_AREA)
        out.append(r)
    return np.stack(out), forces


def split_by_pose(groups: dict, fraction: float, seed: int = 0) -> tuple[list[int], list[int]]:
    """Split row indices so that all images of one contact pose fall on the same side.

    ``groups``: {(object, pose_id): [row indices]}; returns (kept, held_out) with about
    ``fraction`` of the poses of every object held out (at least one when fraction > 0).
    """
    if not 0 <= fraction < 1:
        raise ValueError(f"held-out fraction must be in [0, 1), got {fraction}")
    rng = np.random.default_rng(seed)
    by_object: dict = {}
    for key in sorted(groups):
        by_object.setdefault(key[0], []).append(key)
    kept, held = [], []
    for obj in sorted(by_object):
        keys = by_object[obj]
        n_held = 0 if fraction == 0 else max(1, int(round(fraction * len(keys))))
        n_held = min(n_held, len(keys) - 1)
        order = rng.permutation(len(keys))
        for j, k in enumerate(order):
            (held if j < n_held else kept).extend(groups[keys[k]])
    return sorted(kept), sorted(held)
