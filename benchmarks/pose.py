"""Stage 2: pose-conditioned generation, its robustness to the mask, its speed, and pose estimation with it.

    python -m benchmarks.pose --out benchmarks/results/pose.json [--quick] [--sheet FILE.png]

Data: sensor-model scenes (``controltac_il.generator.training.pose_data``) on the nominal GelSight Mini at
120x160, with seeds the adapter never saw: "seen" = the six training objects, "unseen" = the held-out objects;
every pair moves the contact to another pose (and another force, Fz in the validated range). The condition is the
reference's geometric contact mask carried to the target pose (``object_mask`` + ``transform`` through the
API); ``pose_control_image_mask`` uses the reference frame's contact pixels (``contact_mask``) instead, as a lab
would. Metrics on images (residual + background): MSE (0-255 RGB) and SSIM, mean ± SD, beside a copy of the
reference and stage 1 alone (ΔF only: it cannot move the contact).

- ``pose_control``: the errors per split, and ``unseen_mse`` / ``stage1_only_unseen_mse`` / ``copy_unseen_mse``.
- ``robustness``: the unseen pairs with the target mask scaled (0.8-1.2), shifted (2-6 px, random direction),
  rotated (2-6°, random sign) and all three at the extremes (the paper's appendix; ``--quick``: the last only).
- ``speed``: images/s at batch 32 with and without the mask (median of repeats, this process's torch threads), and
  per DDIM step count (1, 2, 5, 10) the speed with the unseen error beside it.
- ``moved_contacts_240``: the real GelSight Mini frames of ``../shared`` (only figures are written) and sensor-model
  contacts of the held-out objects at 240x320, their contact pixels moved by four rigid moves: IoU of the generated
  contact with the moved mask, centroid error, area ratio and the old contact left behind.
- ``pose_estimation``: a CNN estimating (x, y, θ) trained on few sensor-model ("real") frames, on frames stage 2
  generates from them at new poses, and on both; errors on held-out frames of generator-seen and -unseen
  objects, beside the PCA baseline on the frames' contact pixels (``benchmarks.pose_estimation``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import base_parser, median_time, print_table, write_results
from benchmarks.generator import error_map, quality
from benchmarks.response import real_references, sim_references
from benchmarks.pose_estimation import fit_cnn, fit_pca, pose_errors, predict_cnn, predict_pca
from controltac_il.generator import ForceGenerator
from controltac_il.generator.config import FZ_RANGE, SHEAR_MAX
from controltac_il.generator.training.pose_data import POSE_SPREAD, PoseScenes, render_scenes
from controltac_il.generator.shipped import SHIPPED_ADAPTERS, locate_checkpoint
from controltac_il.io import atomic_path, write_json
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, contact_mask, from_residual
from controltac_il.tactile.residual import residual_magnitude
from controltac_il.tactile.pose import mask_centroid, move_mask, transform_between

SIZE = (120, 160)
SPLITS = {"seen": (TRAIN_OBJECTS, 2001), "unseen": (HELDOUT_OBJECTS, 2002)}
# pose estimation: objects whose angle is defined modulo π (no 4-fold or round symmetry)
ESTIMATION = {"seen": ("slim_cylinder", "thin_cylinder", "triple_cylinder"), "unseen": ("t_shape", "usb_c", "cube_edge")}
PERTURBATIONS = {"scale 0.8": (0.8, 0, 0), "scale 0.9": (0.9, 0, 0), "scale 1.1": (1.1, 0, 0), "scale 1.2": (1.2, 0, 0),
                 "shift 2 px": (1, 2, 0), "shift 4 px": (1, 4, 0), "shift 6 px": (1, 6, 0),
                 "rotate 2°": (1, 0, 2), "rotate 4°": (1, 0, 4), "rotate 6°": (1, 0, 6),
                 "combined 0.8, 6 px, 6°": (0.8, 6, 6), "combined 1.2, 6 px, 6°": (1.2, 6, 6)}

PROG = "python -m benchmarks.pose"


def cross_pose_pairs(scenes: PoseScenes, max_pairs: int, seed: int) -> np.ndarray:
    """(P, 2) (reference, target) index pairs within scenes whose poses differ, at most ``max_pairs``."""
    pairs = [(i, j) for m in scenes.members() for i in m for j in m
             if not np.array_equal(scenes.poses[i], scenes.poses[j])]
    rng = np.random.default_rng(seed)
    pairs = np.asarray(pairs)
    return pairs[np.sort(rng.permutation(len(pairs))[:max_pairs])]


def moves(scenes: PoseScenes, pairs: np.ndarray) -> np.ndarray:
    """(P, 3) mask transforms (dx_px, dy_px, dtheta) carrying each reference's contact to its target's pose."""
    return np.asarray([transform_between(scenes.poses[i], scenes.poses[j], scenes.masks[i], scenes.mm_per_px)
                       for i, j in pairs])


def perturbed(masks: np.ndarray, scale: float, shift_px: float, rot_deg: float, seed: int) -> np.ndarray:
    """Each mask scaled about its centroid, shifted by ``shift_px`` in a random direction, rotated by ±``rot_deg``."""
    rng = np.random.default_rng(seed)
    out = []
    for m in masks:
        a = rng.uniform(0, 2 * np.pi)
        t = (shift_px * np.cos(a), shift_px * np.sin(a), np.radians(rot_deg) * rng.choice((-1, 1)))
        try:
            out.append(move_mask(m, t, scale))
        except ValueError:  # moved off the pad: keep the unperturbed mask
            out.append(m)
    return np.stack(out)


def pair_arrays(scenes: PoseScenes, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(reference residuals, target residuals, backgrounds, ΔF (P, 3) N) of (P, 2) index pairs."""
    ref, tgt = scenes.residuals[pairs[:, 0]], scenes.residuals[pairs[:, 1]]
    return ref, tgt, scenes.backgrounds[scenes.scene[pairs[:, 0]]], scenes.forces[pairs[:, 1]] - scenes.forces[pairs[:, 0]]


def evaluate_split(gen: ForceGenerator, scenes: PoseScenes, pairs: np.ndarray) -> dict:
    ref, tgt, bg, df = pair_arrays(scenes, pairs)
    t = moves(scenes, pairs)
    pose = gen.generate(ref, df, object_mask=scenes.masks[pairs[:, 0]], transform=t)
    # what a lab has: the reference frame's contact pixels, moved (the simulator's moved footprint where there are
    # none, or where they would leave the pad)
    masks, fallback = [], 0
    for (i, j), r in zip(pairs, ref):
        try:
            px = contact_mask(r)
            masks.append(move_mask(px, transform_between(scenes.poses[i], scenes.poses[j], px, scenes.mm_per_px)))
        except ValueError:
            masks.append(move_mask(scenes.masks[i], transform_between(scenes.poses[i], scenes.poses[j], scenes.masks[i],
                                                                       scenes.mm_per_px)))
            fallback += 1
    from_image = gen.generate(ref, df, mask=np.stack(masks))
    stage1 = gen.generate(ref, df)
    return {"pose_control": quality(pose, tgt, bg, ref), "stage1_only": quality(stage1, tgt, bg, ref),
            "pose_control_image_mask": {**quality(from_image, tgt, bg, ref), "footprint_fallbacks": fallback},
            "copy": quality(ref, tgt, bg, ref), "pairs": int(len(pairs)),
            "mean_move_px": float(np.hypot(t[:, 0], t[:, 1]).mean()), "mean_turn_deg": float(np.degrees(np.abs(t[:, 2])).mean()),
            "_outputs": (ref, tgt, pose, stage1, bg)}


def robustness(gen: ForceGenerator, scenes: PoseScenes, pairs: np.ndarray, copy_mse: float, quick: bool) -> dict:
    ref, tgt, bg, df = pair_arrays(scenes, pairs)
    masks = np.stack([move_mask(scenes.masks[i], t) for i, t in zip(pairs[:, 0], moves(scenes, pairs))])
    out = {}
    cases = {"none": (1, 0, 0), **PERTURBATIONS}
    if quick:
        cases = {k: cases[k] for k in ("none", "combined 1.2, 6 px, 6°")}
    for k, (name, (scale, shift, rot)) in enumerate(cases.items()):
        q = quality(gen.generate(ref, df, mask=perturbed(masks, scale, shift, rot, k)), tgt, bg, ref)
        out[name] = {"mse": q["mse"], "ssim": q["ssim"], "ratio_to_copy": q["mse"] / copy_mse}
    return out


def speed(gen: ForceGenerator, scenes: PoseScenes, pairs: np.ndarray, copy_mse: float, repeats: int, steps_grid) -> dict:
    """Images/s at batch 32 with the mask and without (stage 1) at the default steps, and per DDIM step count the
    speed with the unseen pairs' MSE ratio to a copy beside it."""
    idx = np.arange(32) % len(scenes.residuals)
    ref, masks = scenes.residuals[idx], scenes.masks[idx]
    df = np.tile([[0.0, 0.0, 1.0]], (32, 1))
    warmup = int(repeats > 1)
    t_mask = median_time(lambda: gen.generate(ref, df, mask=masks), repeats=repeats, warmup=warmup)
    t_plain = median_time(lambda: gen.generate(ref, df), repeats=repeats, warmup=warmup)
    p_ref, p_tgt, bg, p_df = pair_arrays(scenes, pairs)
    t = moves(scenes, pairs)
    grid = []
    for steps in steps_grid:
        q = quality(gen.generate(p_ref, p_df, object_mask=scenes.masks[pairs[:, 0]], transform=t, steps=steps), p_tgt, bg, p_ref)
        sec = median_time(lambda: gen.generate(ref, df, mask=masks, steps=steps), repeats=repeats)
        grid.append({"steps": steps, "img_per_s": 32 / sec, "unseen_mse_ratio_to_copy": q["mse"] / copy_mse, "unseen_ssim": q["ssim"]})
    return {"batch": 32, "size": list(SIZE), "steps": gen.config.default_steps,
            "pose_img_per_s": 32 / t_mask, "stage1_img_per_s": 32 / t_plain, "steps_grid": grid}


REAL_MOVES = {"right 40 px": (40, 0, 0), "up 30 px": (0, -30, 0), "turn 30°": (0, 0, 30),
              "left 40 px, down 25 px, turn 45°": (-40, 25, 45)}  # at 240x320 (dθ in degrees)


def moved_contact_metrics(gen: ForceGenerator, references: dict[str, np.ndarray]) -> dict:
    """Each reference's contact pixels (``contact_mask``) moved by each of ``REAL_MOVES`` through the API (ΔF = 0):
    how far the generated frame's contact pixels are from the moved mask. iou: with the moved mask; centroid_error_px;
    area_ratio: generated / moved contact area; old_contact_left: share of the old contact's pixels outside the moved
    mask still in contact (a ghost: 0 is ideal). These threshold the generated frame (``contact_mask``, 12 grey
    levels), so a fainter contact scores lower; without a threshold: energy_in_target / energy_left_behind, the share
    of the frame's residual magnitude above the bare gel's inside the moved mask (dilated 3 px) / on the old contact
    outside it, beside the reference's own share inside its mask (``reference_energy_in_contact``)."""
    out = {}
    for name, ref in references.items():
        m, rows = contact_mask(ref), {}
        def shares(res, inside, behind=None):
            e = np.clip(residual_magnitude(res) - np.median(residual_magnitude(res)), 0, None)
            near = cv2.dilate(inside.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
            return float(e[near].sum() / e.sum()), (None if behind is None else float(e[behind & ~near].sum() / e.sum()))
        for label, (dx, dy, deg) in REAL_MOVES.items():
            try:
                want = move_mask(m, (dx, dy, np.radians(deg)))
            except ValueError:
                continue
            generated = gen.generate(ref[None], [[0.0, 0.0, 0.0]], mask=want)[0]
            got = contact_mask(generated)
            old = m & ~want
            rows[label] = {"iou": float((got & want).sum() / max((got | want).sum(), 1)),
                           "centroid_error_px": float(np.hypot(*np.subtract(mask_centroid(got), mask_centroid(want))))
                           if got.any() else None,
                           "area_ratio": float(got.sum() / want.sum()),
                           "old_contact_left": float((got & old).sum() / old.sum()) if old.any() else None}
            rows[label]["energy_in_target"], rows[label]["energy_left_behind"] = shares(generated, want, old)
        out[name] = {"contact_pixels": int(m.sum()), "reference_energy_in_contact": shares(ref, m)[0], "moves": rows}
    return out


def generated_views(gen: ForceGenerator, real: PoseScenes, per_frame: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Stage-2 frames at new random poses and forces from each real frame: (residuals, poses (N, 3))."""
    rng = np.random.default_rng(seed)
    half_h, half_w = (s * real.mm_per_px / 2 for s in SIZE)
    forces, masks, poses, idx = [], [], [], []
    for i in range(len(real.residuals)):
        for _ in range(per_frame):
            for _attempt in range(20):  # a pose that keeps most of the contact on the pad (else none from this draw)
                pose = np.array([rng.uniform(-POSE_SPREAD, POSE_SPREAD) * half_w,
                                 rng.uniform(-POSE_SPREAD, POSE_SPREAD) * half_h, rng.uniform(0, np.pi)])
                try:
                    m = move_mask(real.masks[i], transform_between(real.poses[i], pose, real.masks[i], real.mm_per_px))
                except ValueError:
                    continue
                if m.sum() >= 0.5 * real.masks[i].sum():
                    idx.append(i)
                    masks.append(m)
                    poses.append(pose)
                    forces.append([*rng.uniform(-SHEAR_MAX, SHEAR_MAX, 2), rng.uniform(*FZ_RANGE)])
                    break
    idx = np.asarray(idx)
    out = gen.generate(real.residuals[idx], np.asarray(forces) - real.forces[idx], mask=np.stack(masks),
                       seed=[int(s) for s in rng.integers(0, 2**31, len(idx))])
    return out, np.asarray(poses)


def pose_estimation(gen: ForceGenerator, quick: bool) -> dict:
    objects = [*ESTIMATION["seen"], *ESTIMATION["unseen"]]
    real = render_scenes(objects, 1, 2 if quick else 4, 2 if quick else 3, 3001, SIZE, None, progress=False)
    test = render_scenes(objects, 1, 3 if quick else 10, 2, 3002, SIZE, None, progress=False)
    half = tuple(s * real.mm_per_px / 2 for s in SIZE)
    gen_res, gen_poses = generated_views(gen, real, 1 if quick else 8, 3003)
    steps = 20 if quick else 1500
    sets = {"real": (real.residuals, real.poses), "generated": (gen_res, gen_poses),
            "real + generated": (np.concatenate([real.residuals, gen_res]), np.concatenate([real.poses, gen_poses]))}
    test_obj = [test.objects[s] for s in test.scene]
    out = {"frames": {"real": int(len(real.residuals)), "generated": int(len(gen_res)), "test": int(len(test.residuals))},
           "objects": ESTIMATION, "cnn_steps": steps}
    for name, (x, y) in sets.items():
        pred = predict_cnn(fit_cnn(x, y, half, steps, seed=0), test.residuals, half)
        out[name] = {split: pose_errors(pred[np.isin(test_obj, objs)], test.poses[np.isin(test_obj, objs)])
                     for split, objs in ESTIMATION.items()}
    def image_masks(res):  # what a lab has: the contact pixels of the frame, not the simulator's footprint
        return np.stack([contact_mask(r) for r in res])
    offsets = fit_pca(image_masks(real.residuals), real.poses, [real.objects[s] for s in real.scene])
    pred = predict_pca(image_masks(test.residuals), test_obj, offsets, test.mm_per_px)
    out["pca baseline"] = {split: pose_errors(pred[np.isin(test_obj, objs)], test.poses[np.isin(test_obj, objs)])
                           for split, objs in ESTIMATION.items()}
    return out


def save_sheet(path: Path, rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """PNG, one row per case: reference | target mask | target | generated | stage 1 only | |error| x4 (2x size)."""
    tiles = []
    for label, ref, mask, tgt, gen, s1, bg in rows:
        m = np.repeat(mask[..., None].astype(np.uint8) * 255, 3, -1)
        imgs = [from_residual(ref, bg), m, from_residual(tgt, bg), from_residual(gen, bg), from_residual(s1, bg),
                error_map(gen, tgt)]
        row = np.concatenate([cv2.resize(im, (im.shape[1] * 2, im.shape[0] * 2), interpolation=cv2.INTER_NEAREST)
                              for im in imgs], 1)
        cv2.putText(row, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        tiles.append(row)
    header = np.zeros((24, tiles[0].shape[1], 3), np.uint8)
    w = tiles[0].shape[1] // 6
    for k, name in enumerate(("reference", "target mask", "target", "generated", "stage 1 only", "|error| x4")):
        cv2.putText(header, name, (k * w + 6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    with atomic_path(path, suffix=".png") as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(np.concatenate([header, *tiles], 0), cv2.COLOR_RGB2BGR))


def report(results: dict) -> None:
    """The run's tables: splits, mask robustness, moved contacts, speed, pose estimation."""
    rows = [{"split": s, "method": m, "MSE": f"{r[m]['mse']:.1f} ± {r[m]['mse_sd']:.1f}", "SSIM": f"{r[m]['ssim']:.3f}",
             "ratio to copy": r[m]["mse"] / r["copy"]["mse"]}
            for s, r in results["splits"].items() for m in ("copy", "stage1_only", "pose_control", "pose_control_image_mask")]
    print_table(rows, ["split", "method", "MSE", "SSIM", "ratio to copy"], "pose-conditioned generation (120x160)")
    print_table([{"mask": k, **v} for k, v in results["robustness"].items()], ["mask", "mse", "ssim", "ratio_to_copy"],
                "mask robustness (unseen objects)")
    print_table([{"reference": k, "move": m, **v} for k, r in results["moved_contacts_240"].items()
                 for m, v in r["moves"].items()], ["reference", "move", "iou", "centroid_error_px", "area_ratio",
                                                   "old_contact_left", "energy_in_target", "energy_left_behind"],
                "moved contacts at 240x320 (ΔF = 0)")
    print_table([results["speed"]], ["batch", "steps", "pose_img_per_s", "stage1_img_per_s"], "speed (images/s)")
    if results["speed"]["steps_grid"]:
        print_table(results["speed"]["steps_grid"], ["steps", "img_per_s", "unseen_mse_ratio_to_copy", "unseen_ssim"],
                    "speed against error (DDIM steps, batch 32, unseen objects)")
    pe = results["pose_estimation"]
    print_table([{"trained on": k, **{f"{s} {m}": pe[k][s][m] for s in ESTIMATION for m in ("xy_mm", "theta_deg")}}
                 for k in ("real", "generated", "real + generated", "pca baseline")],
                ["trained on", *(f"{s} {m}" for s in ESTIMATION for m in ("xy_mm", "theta_deg"))],
                f"pose estimation ({pe['frames']})")


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--checkpoint", default="default", help="stage-1 generator (shipped name or folder)")
    p.add_argument("--adapter", default="pose", help="stage-2 pose adapter (shipped name or folder)")
    p.add_argument("--pairs", type=int, default=96, help="evaluation pairs per split (default 96)")
    p.add_argument("--sheet", type=Path, default=None, help="PNG sheet (default: beside --out, .png)")
    p.add_argument("--update-model-card", action="store_true", help="write the figures into the adapter's model_card.json")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    gen = ForceGenerator.from_pretrained(a.checkpoint, pose_adapter=a.adapter)
    n_pairs = 12 if a.quick else a.pairs
    results: dict = {"checkpoint": a.checkpoint, "adapter": a.adapter, "stage1_hash": gen.checkpoint_hash,
                     "size": list(SIZE), "steps": gen.config.default_steps, "splits": {}}
    sheet_rows, scenes_of = [], {}
    for split, (objects, seed) in SPLITS.items():
        scenes = render_scenes(objects, 1 if a.quick else 4, 3, 2, seed, SIZE, None, progress=False)
        pairs = cross_pose_pairs(scenes, n_pairs, seed)
        r = evaluate_split(gen, scenes, pairs)
        ref, tgt, pose, s1, bg = r.pop("_outputs")
        results["splits"][split] = r
        scenes_of[split] = (scenes, pairs)
        masks = [move_mask(scenes.masks[i], t) for i, t in zip(pairs[:3, 0], moves(scenes, pairs[:3]))]
        sheet_rows += [(f"{split} {scenes.objects[scenes.scene[pairs[k, 0]]]}", ref[k], masks[k], tgt[k], pose[k], s1[k], bg[k])
                       for k in range(min(3, len(pairs)))]
    u = results["splits"]["unseen"]
    results["pose_control"] = {"unseen_mse": u["pose_control"]["mse"], "stage1_only_unseen_mse": u["stage1_only"]["mse"],
                               "copy_unseen_mse": u["copy"]["mse"], "unseen_ssim": u["pose_control"]["ssim"],
                               **{f"seen_{k}": results["splits"]["seen"][m]["mse"]
                                  for k, m in (("mse", "pose_control"), ("stage1_only_mse", "stage1_only"), ("copy_mse", "copy"))}}
    copy_mse = u["copy"]["mse"]
    results["robustness"] = robustness(gen, *scenes_of["unseen"], copy_mse, a.quick)
    results["speed"] = speed(gen, *scenes_of["unseen"], copy_mse, 1 if a.quick else 7, () if a.quick else (1, 2, 5, 10))
    results["pose_estimation"] = pose_estimation(gen, a.quick)
    # the real GelSight Mini frames of ../shared (measured, never written) beside sensor-model contacts at 240x320
    sim = {k: v for k, v in sim_references(HELDOUT_OBJECTS[:2] if a.quick else HELDOUT_OBJECTS, (240, 320)).items()
           if 0 < contact_mask(v).sum() < 0.5 * v.shape[0] * v.shape[1]}  # a contact to move, not larger than half the pad
    results["moved_contacts_240"] = moved_contact_metrics(gen, {**({} if a.quick else real_references()), **sim})
    results["wall_s"] = round(time.perf_counter() - t0, 1)

    report(results)
    if a.sheet or a.out:
        save_sheet(a.sheet or a.out.with_suffix(".png"), sheet_rows)
    doc = write_results(a.out, results)
    if a.update_model_card:
        card_path = locate_checkpoint(a.adapter, SHIPPED_ADAPTERS) / "model_card.json"
        card = json.loads(card_path.read_text())
        card["benchmark"] = {"command": "python -m benchmarks.pose" + (" --quick" if a.quick else ""),
                             "machine": doc["machine"], **{k: results[k] for k in ("pose_control", "robustness", "speed")}}
        write_json(card_path, card)
        print(f"updated {card_path}")
    return doc


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
