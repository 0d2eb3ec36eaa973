"""ForceAugment on real GelSight Mini frames without force labels: what to do with an estimated reference force
outside the generator's validated range (``ForceAugmentConfig.estimated_reference``).

    python -m benchmarks.unlabelled_real --out unlabelled_real.json [--frames DIR]

Data: the real frames of ``../shared/data/real_gelsight_mini`` (GPL-3.0: measured against here, never copied
into the project): a background and light presses of a bead, a key and a seed. As a lab records them, in
LeRobot's convention (the sensor a camera ``observation.images.gelsight``, float (3, H, W) in [0, 1], no labels,
no background): 3 episodes x 12 frames, 3 without contact then 9 of the press; ``copies=2``.

Per policy (skip: today's; clip: Fz clipped into the range, no shear; nominal: (0, 0, 5.5) N):
- ``summary()``: the share of the copies' contact frames regenerated (target >= 80 %);
- on each press, the shipped generator asked for ΔFz in ``SWEEP`` from the policy's working reference: the ΔFz
  applied (after the generator's clamp to its range), the contact area (pixels of ``contact_mask``) against it
  (non-decreasing wanted), identity at ΔF = 0 (MSE to the reference residual, uint8 units) and invented contact
  (contact pixels of a ΔFz <= 0 frame outside the reference's contact grown by 3 px, share of the frame).
The shipped estimator's readings of the presses are reported beside (no label exists for them: a light press
of a small object is a few N with well under 1 N of shear). Picture (``OUT.png``, the nominal policy):
reference and ΔFz = -3, 0, +3 per press; made from the GPL frames, so it is git-ignored, never committed.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from benchmarks.common import REAL_GELSIGHT, REAL_PRESSES, base_parser, print_table, real_gelsight, write_results
from controltac_il.augment import ForceAugment
from controltac_il.augment.reference import working_reference
from controltac_il.streams import LEROBOT, tactile_key
from controltac_il.tactile.residual import contact_mask, from_residual, to_residual
from controltac_il.tactile.sheet import save_png

POLICIES = ("skip", "clip", "nominal")
SWEEP = (-4.0, -3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0)
KEY = tactile_key("gelsight", LEROBOT)

PROG = "python -m benchmarks.unlabelled_real"


class RealPresses(Dataset):
    """The presses as LeRobot items: episode e = 3 background frames then 9 frames of press e."""

    def __init__(self, background: np.ndarray, presses: list[np.ndarray]):
        self.frames = [(e, t, background if t < 3 else p) for e, p in enumerate(presses) for t in range(12)]

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> dict:
        e, t, img = self.frames[i]
        return {KEY: torch.from_numpy(img).permute(2, 0, 1).float() / 255, "episode_index": torch.tensor(e),
                "frame_index": torch.tensor(t), "index": torch.tensor(i), "task_index": torch.tensor(0),
                "timestamp": torch.tensor(t / 10, dtype=torch.float32), "task": "press"}


def sweep(gen, residual: np.ndarray, reference: np.ndarray) -> dict:
    """ΔFz applied, contact area, identity and invented contact of one press from ``reference`` (3,) N."""
    n = len(SWEEP)
    refs = np.repeat(reference[None], n, 0)
    targets = refs + np.array([[0.0, 0.0, d] for d in SWEEP])
    res = gen.generate_at(np.repeat(residual[None], n, 0), refs, targets, out_of_range="clamp",
                          reference_out_of_range="skip", seed=0)
    applied = (res.decision.target - refs)[:, 2] * res.decision.generated
    area = contact_mask(res.residuals).sum(axis=(1, 2))
    grown = cv2.dilate(contact_mask(residual[None])[0].astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    invented = [float((contact_mask(r[None])[0] & ~grown).mean()) for r, d in zip(res.residuals, applied) if d <= 0]
    zero = SWEEP.index(0.0)
    return {"applied_dfz": applied.round(3).tolist(), "contact_px": area.tolist(),
            "reference_contact_px": int(contact_mask(residual[None]).sum()),
            "area_non_decreasing": bool(np.all(np.diff(area[np.argsort(applied, kind="stable")]) >= 0)),
            "identity_mse": float(((res.residuals[zero].astype(float) - residual) ** 2).mean()),
            "invented_contact_max": max(invented), "generated": res.decision.generated.tolist(),
            "images": res.residuals}


def policy_row(gen, estimator, data, residuals, estimates, policy: str) -> dict:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        aug = ForceAugment(data, gen, estimator=estimator, tactile_keys=[KEY], copies=2, mode="online",
                           estimated_reference=policy, progress=False)
        s = aug.summary()
    contact = s["tactile_frames"] - s["no_contact"]
    refs = working_reference(estimates, policy)
    sweeps = [sweep(gen, r, f) for r, f in zip(residuals, refs)]
    return {"policy": policy, "summary": s, "contact_frames": contact,
            "regenerated_share": (s["regenerated"] + s["clamped"]) / contact if contact else 0.0,
            "working_reference": refs.round(3).tolist(), "presses": dict(zip(REAL_PRESSES, sweeps)),
            "warnings": sorted({str(w.message) for w in caught if "force estimator" in str(w.message)})}


def picture(path: Path, background: np.ndarray, residuals, row: dict) -> None:
    """Reference and ΔFz = -3, 0, +3 of each press under one policy (images as the sensor shows them)."""
    cols = [SWEEP.index(d) for d in (-3.0, 0.0, 3.0)]
    lines = []
    for name, res in zip(REAL_PRESSES, residuals):
        images = row["presses"][name]["images"]
        lines.append(np.concatenate([from_residual(res, background)] + [from_residual(images[c], background)
                                                                         for c in cols], axis=1))
    save_png(path, np.ascontiguousarray(np.concatenate(lines, axis=0)[::2, ::2]))


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--frames", type=Path, default=REAL_GELSIGHT, help=f"folder of the real frames (default {REAL_GELSIGHT})")
    args = p.parse_args(argv)
    from controltac_il.estimators import ForceEstimator
    from controltac_il.generator import ForceGenerator

    torch.set_num_threads(2)
    gen, estimator = ForceGenerator.from_pretrained(), ForceEstimator.from_pretrained()
    background, presses = real_gelsight(args.frames)  # a missing frame: one line naming it (guard)
    presses = list(presses.values())
    residuals = [to_residual(p, background) for p in presses]
    estimates = estimator.predict(np.stack(residuals)).astype(np.float64)
    data = RealPresses(background, presses)
    rows = [policy_row(gen, estimator, data, residuals, estimates, policy) for policy in POLICIES]
    table = [{"policy": r["policy"], "regenerated": f"{r['summary']['regenerated'] + r['summary']['clamped']}/"
              f"{r['contact_frames']}", **{f"{n} area monotone": r["presses"][n]["area_non_decreasing"] for n in REAL_PRESSES},
              "identity MSE": max(r["presses"][n]["identity_mse"] for n in REAL_PRESSES),
              "invented": max(r["presses"][n]["invented_contact_max"] for n in REAL_PRESSES)} for r in rows]
    print_table(table, list(table[0]), title="estimated references outside the range, per policy (real frames)")
    if args.out is not None:
        picture(args.out.with_suffix(".png"), background, residuals, rows[POLICIES.index("nominal")])
    for r in rows:
        for sw in r["presses"].values():
            sw.pop("images")
    return write_results(args.out, {
        "benchmark": "unlabelled_real", "frames": "shared/data/real_gelsight_mini (GPL-3.0, measured against only)",
        "generator_hash": str(gen.checkpoint_hash), "estimator_hash": str(estimator.checkpoint_hash),
        "estimates_n": dict(zip(REAL_PRESSES, estimates.round(2).tolist())), "sweep_dfz": list(SWEEP), "policies": rows,
        "target_regenerated_share": 0.8})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
