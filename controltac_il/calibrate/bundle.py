"""The calibration bundle: the estimator's colour adapter and the generator's fine-tune, each measured on held-out
grasps, written under ``OUT.partial`` and renamed to OUT when complete.

A grasp (a press) is one contact pose: (object, pose_id) of the presses layout. Below FINETUNE_FROM frames the
estimator gets the colour adapter (``estimators.few_shot``), measured leaving one grasp out (each grasp scored by
an adapter fitted on the others, against the others' mean Fz), then fitted on all grasps; from there on the whole
network is fine-tuned without the held-out grasps (``--val-fraction``) and scored on them. Whether ForceAugment
may use it is decided over those held-out grasps (``decision``). The generator is fine-tuned without the held-out
grasps (``--val-fraction``) and scored on pairs of their frames with |ΔFz| >= MIN_PAIR_DFZ, against a copy of the
reference.
"""

from __future__ import annotations

import os
import shutil
from collections import Counter
from pathlib import Path

import numpy as np

from controltac_il.calibrate.decision import MIN_GRASPS, decide, per_grasp
from controltac_il.generator.shipped import BUNDLE_PART as GENERATOR_PART

FINETUNE_FROM = 500  # frames: from here "auto" fine-tunes the whole estimator (benchmarks/results/finetune.json: Fz MAE
#                      0.40 N at 2 016 frames, the adapter 0.89 N at 480), below it fits the colour adapter
STEPS = {"adapter": 150, "finetune": 1000}  # the estimator's default steps per method
MIN_PAIR_DFZ = 1.5  # N: held-out generator pairs differ at least this much in Fz
MAX_PAIRS = 96


def held_out_poses(groups: dict, fraction: float) -> tuple[list[int], list[int]]:
    """(train, validation) rows, whole contact poses apart, about ``fraction`` of the poses held out: that share of
    each object's poses where every object has at least 1 / fraction of them, else that share of all poses (at
    least one; one per object would hold out half of two poses each); ValueError for a single pose."""
    from controltac_il.estimators.data import split_by_pose

    if len(groups) < 2:
        raise ValueError("the labelled frames hold one contact pose only; at least two are needed (one is held out "
                         "for validation)")
    if min(Counter(obj for obj, _ in groups).values()) * fraction >= 1 - 1e-9:  # poses of the sparsest object
        return split_by_pose(groups, fraction, seed=0)
    keys = sorted(groups)
    n_held = min(max(1, round(fraction * len(keys))), len(keys) - 1)
    picked = {keys[i] for i in np.random.default_rng(0).permutation(len(keys))[:n_held]}
    return ([r for k in keys if k not in picked for r in groups[k]], [r for k in keys if k in picked for r in groups[k]])


def grasp_ids(ds) -> np.ndarray:
    """Grasp index (N,) of every row of a presses dataset: its contact pose's rank."""
    out = np.empty(len(ds), int)
    for g, rows in enumerate(ds.pose_groups().values()):
        out[rows] = g
    return out


def cross_validated(base, residuals: np.ndarray, fz: np.ndarray, grasps: np.ndarray, steps: int) -> dict:
    """The colour adapter's held-out Fz per frame, leaving one grasp out, and its table against the constant (the
    other grasps' mean Fz), with the per-grasp rows and the decision (``decision``)."""
    from controltac_il.estimators.few_shot import ColourFit, fit_colour_adapter

    ids = np.unique(grasps)
    if len(ids) < MIN_GRASPS:  # checked before any fit: no interval over grasps exists
        raise ValueError(f"the labelled frames hold {len(ids)} contact poses; at least {MIN_GRASPS} are needed (each "
                         "is scored by an adapter fitted without it)")
    pred, const = np.empty(len(fz)), np.empty(len(fz))
    for g in ids:
        out = grasps == g
        est = fit_colour_adapter(base, residuals[~out], fz[~out], ColourFit(steps=steps))
        pred[out] = est.predict(residuals[out], gate=False)[:, 2]
        const[out] = fz[~out].mean()
    return held_out_table(pred, fz, const, grasps)


def held_out_table(pred: np.ndarray, fz: np.ndarray, constant: np.ndarray, grasps: np.ndarray) -> dict:
    """The estimator's held-out table: pred (N,) Fz N, NaN where not held out; the constant's prediction (N,) N."""
    from controltac_il.estimators.few_shot import held_out_mae

    held = np.isfinite(pred)
    rows = per_grasp(pred, fz, constant, grasps)
    return {**held_out_mae(pred[held], fz[held], constant[held]), "grasps": len(rows), "per_grasp": rows,
            "decision": decide(rows), "predicted_fz": [float(v) if np.isfinite(v) else None for v in pred]}


def estimator_method(args, frames: int) -> str:
    """"adapter" or "finetune": ``--estimator-method``, or by the number of labelled frames when "auto"."""
    if args.estimator_method != "auto":
        return args.estimator_method
    return "finetune" if frames >= FINETUNE_FROM else "adapter"


def finetuned(args, ds, base, x, f, grasps, staging: Path):
    """(the base estimator fine-tuned on all axes, its table on held-out grasps: ``--val-fraction`` of them, at least
    ``MIN_GRASPS`` so that the decision has its interval; ValueError naming the method where that leaves none to
    train on)."""
    from controltac_il.estimators.config import EstimatorTrainConfig
    from controltac_il.estimators.fit import fit

    groups = ds.pose_groups()
    if len(groups) <= MIN_GRASPS:
        raise ValueError(f"--estimator-method finetune: {len(groups)} grasps; at least {MIN_GRASPS + 1} are needed "
                         f"({MIN_GRASPS} held out to decide whether it is used, one to train on)")
    train, val = held_out_poses(groups, max(args.val_fraction, MIN_GRASPS / len(groups)))
    steps = args.estimator_steps
    cfg = EstimatorTrainConfig(steps=steps, lr=1e-3, min_lr=1e-5, warmup=min(50, steps // 5),
                               checkpoint_every=max(steps // 4, 1))
    state = staging / "estimator.train_state"
    est, _ = fit(x[train], f[train], train=cfg, val=(x[val], f[val]), state_dir=state, init=base,
                 resume=args.resume and (state / "state.json").is_file())
    pred = np.full(len(f), np.nan)
    pred[val] = est.predict(x[val], gate=False)[:, 2]
    return est, held_out_table(pred, f[:, 2].astype(np.float64), np.full(len(f), float(f[train, 2].mean())), grasps)


def estimator_part(args, ds, staging: Path) -> dict:
    """Calibrate the base estimator into its bundle part, ``staging / "estimator"`` (module docstring); its held-out
    table."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.data import load_arrays
    from controltac_il.estimators.estimator import BUNDLE_PART as ESTIMATOR_PART
    from controltac_il.estimators.few_shot import ColourFit, fit_colour_adapter

    base = ForceEstimator.from_pretrained(args.base_estimator)
    x, f = load_arrays(ds, size=(base.config.input_height, base.config.input_width), progress=False)
    grasps, method = grasp_ids(ds), estimator_method(args, len(ds))
    args.estimator_steps = args.estimator_steps or STEPS[method]
    before = float(np.abs(base.predict(x, gate=False)[:, 2] - f[:, 2]).mean())
    if method == "finetune":
        est, table = finetuned(args, ds, base, x, f, grasps, staging)
    else:
        table = cross_validated(base, x, f[:, 2].astype(np.float64), grasps, args.estimator_steps)
        est = fit_colour_adapter(base, x, f[:, 2], ColourFit(steps=args.estimator_steps))
    est.save(staging / ESTIMATOR_PART)
    print(table["decision"]["why"])
    names = {"adapter": "colour adapter (3x3 mix + shift) before the frozen base network",
             "finetune": "the whole base network fine-tuned"}
    return {"base": str(args.base_estimator or "default"), "base_hash": str(base.checkpoint_hash),
            "method": names[method], "steps": args.estimator_steps, "images": len(x), "zero_shot_mae_n": before,
            "held_out": table, "use_estimator": table["decision"]["use"], "grasp_of_frame": grasps.tolist(),
            "true_fz": f[:, 2].astype(float).tolist(),
            "hash": str(ForceEstimator.from_pretrained(staging / ESTIMATOR_PART).checkpoint_hash)}


def subset_presses(ds, rows: list[int], out: Path) -> Path:
    """A presses folder at ``out`` holding only ``rows`` of ``ds`` (manifest rows, their images, backgrounds). Each
    entry is written whole or not at all, so a resumed calibration never reuses a half-copied folder."""
    import csv

    from controltac_il.io import atomic_dir, atomic_path

    out.mkdir(parents=True, exist_ok=True)
    with open(ds.root / "manifest.csv", newline="") as f:
        reader = csv.DictReader(f)
        fields, lines = reader.fieldnames, list(reader)
    with atomic_path(out / "manifest.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(lines[i] for i in rows)
    for name in ("background.png", "backgrounds", "images", "meta.json"):
        src = ds.root / name
        if not src.exists() or (out / name).exists():
            continue
        if src.is_dir():
            with atomic_dir(out / name) as tmp:
                shutil.copytree(src, tmp, dirs_exist_ok=True)
        else:
            with atomic_path(out / name) as tmp:
                shutil.copy2(src, tmp)
    return out


def held_out_pairs(ds, rows: list[int]) -> tuple:
    """(reference residuals, target residuals, ΔF (P, 3) N, reference forces (P, 3) N) of frame pairs within each
    held-out grasp (``generation_error``'s arguments)."""
    f = ds.forces()
    groups: dict = {}
    for i in rows:
        groups.setdefault((ds.records[i].object, ds.records[i].pose_id), []).append(i)
    pairs = [(i, j) for g in groups.values() for i in g for j in g if abs(f[j, 2] - f[i, 2]) >= MIN_PAIR_DFZ]
    if len(pairs) > MAX_PAIRS:
        pairs = [pairs[k] for k in sorted(np.random.default_rng(0).choice(len(pairs), MAX_PAIRS, replace=False))]
    if not pairs:
        return None
    ref = np.stack([ds.residual(i) for i, _ in pairs])
    tgt = np.stack([ds.residual(j) for _, j in pairs])
    return ref, tgt, np.stack([f[j] - f[i] for i, j in pairs]).astype(np.float32), f[[i for i, _ in pairs]]


def generator_part(args, ds, staging: Path) -> dict:
    """Fine-tune the base generator on the training grasps into its bundle part, ``staging / "generator"``; its error
    on held-out pairs."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.training.finetune import fine_tune
    from controltac_il.generator.shipped import locate_checkpoint
    from controltac_il.generator.training.validation import generation_error

    base = locate_checkpoint(args.base_generator)
    train, val = held_out_poses(ds.pose_groups(), args.val_fraction)
    data = subset_presses(ds, train, staging / "generator.data")
    final = fine_tune(base, data, staging / "generator.run", args.dit_steps, args.lr, args.ae_steps, batch=args.batch,
                      threads=args.threads, device=args.device)
    if (staging / GENERATOR_PART).exists():
        shutil.rmtree(staging / GENERATOR_PART)
    shutil.copytree(final, staging / GENERATOR_PART)
    pairs, table = held_out_pairs(ds, val), None
    base_gen, tuned = ForceGenerator.from_pretrained(base), ForceGenerator.from_pretrained(staging / GENERATOR_PART)
    if pairs is not None:
        before, after = generation_error(base_gen, *pairs), generation_error(tuned, *pairs)
        table = {"pairs": len(pairs[0]), "grasps": len({(ds.records[i].object, ds.records[i].pose_id) for i in val}),
                 "zero_shot_ratio_to_copy": before["ratio_to_copy"], "ratio_to_copy": after["ratio_to_copy"],
                 "mse": after["mse"], "copy_mse": after["copy_mse"]}
    return {"base": str(args.base_generator), "base_hash": str(base_gen.checkpoint_hash),
            "ae_steps": args.ae_steps, "dit_steps": args.dit_steps, "lr": args.lr, "train_images": len(train),
            "held_out_rows": list(map(int, val)), "held_out": table,
            "hash": str(tuned.checkpoint_hash)}


def run(args, ds, source: dict | None = None) -> dict:
    """Write the bundle (module docstring); returns its calibration record."""
    from controltac_il.calibrate.report import card, save_report
    from controltac_il.io import write_json

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    staging = args.out.with_name(args.out.name + ".partial")
    staging.mkdir(parents=True, exist_ok=True)
    presses = ds.root.resolve()  # recordings are written as presses inside the staging folder: name the final one
    if presses.is_relative_to(staging.resolve()):
        presses = args.out.resolve() / presses.relative_to(staging.resolve())
    record = {"presses": str(presses), "images": len(ds), "source": source,
              "estimator": estimator_part(args, ds, staging), "generator": generator_part(args, ds, staging)}
    write_json(staging / "calibration.json", record)
    save_report(staging / "report.png", record, ds, staging / GENERATOR_PART)
    (staging / "README.md").write_text(card(record))
    for leftover in ("generator.run", "generator.data", "estimator.train_state"):
        shutil.rmtree(staging / leftover, ignore_errors=True)
    os.replace(staging, args.out)
    return record
