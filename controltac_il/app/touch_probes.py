"""What the cameras and the generator can see of the touch-critical scene's in-hand offset and grip force
(``benchmarks.touch_il``): the scene is rendered with one thing changed at a time."""

from __future__ import annotations

import numpy as np

from controltac_il.generator import ForceGenerator
from controltac_il.streams import LOOP, force_key, tactile_key
from controltac_il.tactile.residual import OFFSET, to_residual
from envs.config import PegInHoleConfig
from envs.peg_in_hole import PegInHoleEnv


def stripe_column(residual: np.ndarray) -> float:
    """Column centroid (px) of the contact in a tactile residual uint8 (H, W, 3)."""
    cols = np.abs(residual.astype(np.float32) - OFFSET).sum(axis=2).mean(axis=0)
    cols = np.clip(cols - np.median(cols), 0, None)
    return float((cols * np.arange(cols.size)).sum() / cols.sum())


def vision_check(seeds=range(20), offsets_mm=(-8.0, -5.0, 5.0, 8.0)) -> dict:
    """Can the cameras see the in-hand offset? For each seeded episode, at the start and at the moment
    of insertion (peg 35 mm lower, in the hole's mouth), render every camera with the held peg moved to
    each offset and nothing else changed: ``max_pixel_diff`` 0 means byte-identical images, so no
    model can read the offset from them. The left pad's contact column (px) shows what touch sees."""

    cfg = PegInHoleConfig.touch_critical(tactile_noise=False)
    diffs = {c: 0 for c in cfg.cameras}
    columns = []
    with PegInHoleEnv(cfg) as env:
        for seed in seeds:
            env.reset(seed=seed)
            for moment in ("start", "insertion"):
                if moment == "insertion":
                    a = env.command
                    a[:2] = env.hole_xy - np.array([env.in_hand_offset_m, 0.0])
                    a[2] -= 0.035
                    for _ in range(8):
                        env.step(a)
                images, cols = {c: [] for c in cfg.cameras}, []
                for off in offsets_mm:
                    env.set_peg_offset_in_hand(off / 1000.0)
                    for c in cfg.cameras:
                        images[c].append(env.render_camera(c).astype(np.int16))
                    residual = to_residual(env.render_tactile("left"), env.tactile_background("left"))
                    cols.append(stripe_column(residual))
                for c in cfg.cameras:
                    diffs[c] = max(diffs[c], max(int(np.abs(images[c][0] - im).max()) for im in images[c][1:]))
                columns.append(cols)
    cols = np.asarray(columns)
    return {"episodes": len(list(seeds)), "offsets_mm": list(offsets_mm), "moments": ["start", "insertion"],
            "max_pixel_diff": diffs, "tactile_column_px_mean": cols.mean(axis=0).round(1).tolist(),
            "tactile_column_px_min_step": float(np.abs(np.diff(cols, axis=1)).min().round(1)),
            "tactile_width_px": cfg.tactile_size[1]}


def _contact_stats(residuals: np.ndarray, threshold: float = 6.0) -> tuple[float, float]:
    """(contact area as a fraction of the pad, mean |residual - 127| summed over RGB) of uint8 (N, H, W, 3)."""
    mag = np.abs(residuals.astype(np.float32) - OFFSET).sum(axis=-1)
    return float((mag > threshold).mean()), float(mag.mean())


def grip_response(bands: dict, seeds=range(12), generator: str | None = None) -> dict:
    """Does ForceAugment reach the shifted grip bands, and how well? For each seeded episode the left
    pad's first frame (peg held, nothing else touching) is rendered with the grip at the centre of each
    band: same in-hand pose, only the force changes. The generator turns the nominal frame into each
    band's force (ΔF from the measured pad forces, DDIM default steps); its MSE to the true frame is
    reported beside a reference copy's, with the contact area and intensity of true and generated frames."""

    frames, forces = {}, {}
    for name, (lo, hi) in bands.items():
        grip = (lo + hi) / 2
        cfg = PegInHoleConfig.touch_critical(cameras=(), grip_force_range_n=(grip, grip))
        with PegInHoleEnv(cfg) as env:
            out = [env.reset(seed=s)[0] for s in seeds]
            background = env.tactile_background("left")
        frames[name] = np.stack([to_residual(o[tactile_key("left", LOOP)], background) for o in out])
        forces[name] = np.stack([o[force_key("left", LOOP)] for o in out]).astype(np.float32)
    gen = ForceGenerator.from_pretrained(generator)
    ref, f_ref = frames["nominal"], forces["nominal"]
    rows = {}
    for name in bands:
        res = gen.generate_at(ref, f_ref, forces[name], reference_out_of_range="skip")
        fake = res.residuals
        true = frames[name].astype(np.float32)
        area, mag = _contact_stats(frames[name])
        g_area, g_mag = _contact_stats(fake)
        rows[name] = {"grip_n": (bands[name][0] + bands[name][1]) / 2,
                      "pad_fz_n": float(forces[name][:, 2].mean()),
                      "true_area": area, "true_intensity": mag, "generated_area": g_area, "generated_intensity": g_mag,
                      "generated_mse": float(((fake.astype(np.float32) - true) ** 2).mean()),
                      "copy_mse": float(((ref.astype(np.float32) - true) ** 2).mean()),
                      "clamped": int(res.decision.clamped.sum()),
                      "reference_outside": int(res.decision.reference_outside.sum())}
    return {"episodes": len(list(seeds)), "sensor": "left", "bands": rows}
