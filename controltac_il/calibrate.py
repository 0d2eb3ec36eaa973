"""``python -m controltac_il.calibrate``: fit the force estimator and the generator to a lab's own sensor.

    python -m controltac_il.calibrate --presses DIR --out my_sensor            # then:
    ForceAugment(dataset, generator="my_sensor")                                 # estimator from the bundle too
    python -m controltac_il.augment --generator my_sensor ...
    ForceEstimator.from_pretrained("my_sensor"), ForceGenerator.from_pretrained("my_sensor")

DIR holds presses of the sensor in the FeelAnyForce layout (``manifest.csv``, ``background.png`` or per-sensor
backgrounds, ``images/``: what ``python -m controltac_il.tactile.dataset`` writes). The bundle OUT::

    estimator/          the base estimator fine-tuned on the presses (a checkpoint folder)
    generator/          the base generator, autoencoder then DiT fine-tuned on them (a checkpoint folder)
    calibration.json    the presses, the settings, the bases' hashes, the estimator's MAE per axis on held-out
                        poses of the presses before and after, each part's weights hash
    README.md           the same, for people

Held-out poses (``--val-fraction`` of each object's) are the estimator's validation, never trained on. All is
written under ``OUT.partial`` and renamed to OUT when complete; ``--resume`` continues a stopped run there. Bad
options or a folder that is not in the layout: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path

import numpy as np

PROG = "python -m controltac_il.calibrate"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0].split(": ", 1)[1])
    p.add_argument("--presses", type=Path, required=True, help="the sensor's presses, FeelAnyForce layout (read-only)")
    p.add_argument("--out", type=Path, required=True, help="the bundle folder to write (new)")
    p.add_argument("--base-generator", default="default", help="generator to fine-tune (default: the shipped one)")
    p.add_argument("--base-estimator", default=None, help="estimator to fine-tune (default: the shipped one)")
    p.add_argument("--estimator-steps", type=int, default=1000, help="estimator fine-tuning steps (default 1000)")
    p.add_argument("--ae-steps", type=int, default=600, help="generator autoencoder fine-tuning steps (default 600)")
    p.add_argument("--dit-steps", type=int, default=600, help="generator DiT fine-tuning steps (default 600)")
    p.add_argument("--lr", type=float, default=2e-4, help="peak learning rate of the generator's fine-tunes")
    p.add_argument("--batch", type=int, default=64, help="DiT batch (default 64)")
    p.add_argument("--val-fraction", type=float, default=0.1, help="poses held out for the estimator's MAE")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--resume", action="store_true", help="continue a stopped run in OUT.partial")
    return p


def check(args: argparse.Namespace):
    """The loaded presses; ValueError naming the flag otherwise."""
    from controltac_il.tactile.dataset import load_dataset

    for flag, value, low in (("--estimator-steps", args.estimator_steps, 1), ("--ae-steps", args.ae_steps, 0),
                             ("--dit-steps", args.dit_steps, 1), ("--batch", args.batch, 1)):
        if value < low:
            raise ValueError(f"{flag}: expected an int >= {low}, got {value}")
    if not 0 < args.val_fraction < 1:
        raise ValueError(f"--val-fraction: expected a share in (0, 1), got {args.val_fraction}")
    if args.out.exists():
        raise ValueError(f"--out: {args.out} exists; a bundle is written to a new folder")
    staging = args.out.with_name(args.out.name + ".partial")
    if staging.exists() and not args.resume:
        raise ValueError(f"--out: {staging} holds a stopped run: pass --resume to continue it, or delete it")
    if not args.presses.is_dir():
        raise ValueError(f"--presses: {args.presses} is not a folder")
    try:
        return load_dataset(args.presses)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--presses: not a presses folder in the FeelAnyForce layout ({' '.join(str(exc).split())})") from None


def held_out_poses(groups: dict, fraction: float) -> tuple[list[int], list[int]]:
    """(train, validation) rows, whole contact poses apart: ``fraction`` of each object's poses, else (an object
    with too few) that share of all poses, at least one; ValueError for a single pose."""
    from controltac_il.estimators.data import split_by_pose

    train, val = split_by_pose(groups, fraction, seed=0)
    if val:
        return train, val
    if len(groups) < 2:
        raise ValueError("--presses: one contact pose only; at least two are needed (one is held out for validation)")
    keys = sorted(groups)
    picked = {keys[i] for i in np.random.default_rng(0).permutation(len(keys))[:max(1, round(fraction * len(keys)))]}
    return ([r for k in keys if k not in picked for r in groups[k]], [r for k in keys if k in picked for r in groups[k]])


def estimator_part(args, ds, staging: Path) -> dict:
    """Fine-tune the base estimator into ``staging / "estimator"``; its MAE before and after on held-out poses."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.data import load_arrays
    from controltac_il.estimators.fit import EstimatorTrainConfig, fit, mae_per_axis

    base = ForceEstimator.from_pretrained(args.base_estimator)
    size = (base.config.input_height, base.config.input_width)
    train_idx, val_idx = held_out_poses(ds.pose_groups(), args.val_fraction)
    x, f = load_arrays(ds, train_idx, size=size, progress=True)
    val = load_arrays(ds, val_idx, size=size)
    before = mae_per_axis(base, *val)
    train = EstimatorTrainConfig(steps=args.estimator_steps, lr=1e-3, min_lr=1e-5, warmup=min(50, args.estimator_steps // 5),
                                 checkpoint_every=max(args.estimator_steps // 4, 1))
    est, _ = fit(x, f, train=train, val=val, state_dir=staging / "estimator.train_state", init=base,
                 resume=args.resume and (staging / "estimator.train_state" / "state.json").is_file())
    after = mae_per_axis(est, *val)
    est.save(staging / "estimator")
    return {"base": str(args.base_estimator or "default"), "base_hash": str(base.checkpoint_hash),
            "train_images": len(x), "val_images": len(val[0]), "steps": args.estimator_steps,
            "val_mae_before_n": [round(float(v), 4) for v in before], "val_mae_after_n": [round(float(v), 4) for v in after],
            "hash": str(ForceEstimator.from_pretrained(staging / "estimator").checkpoint_hash)}


def generator_part(args, staging: Path) -> dict:
    """Fine-tune the base generator into ``staging / "generator"``."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.finetune import fine_tune
    from controltac_il.generator.pipeline import locate_checkpoint

    base = locate_checkpoint(args.base_generator)
    final = fine_tune(base, args.presses, staging / "generator.run", args.dit_steps, args.lr, args.ae_steps,
                      batch=args.batch, threads=args.threads)
    if (staging / "generator").exists():
        shutil.rmtree(staging / "generator")
    shutil.copytree(final, staging / "generator")
    return {"base": str(args.base_generator), "base_hash": str(ForceGenerator.from_pretrained(base).checkpoint_hash),
            "ae_steps": args.ae_steps, "dit_steps": args.dit_steps, "lr": args.lr,
            "hash": str(ForceGenerator.from_pretrained(staging / "generator").checkpoint_hash)}


def run(args: argparse.Namespace, ds) -> dict:
    """Write the bundle (module docstring); returns its calibration record."""
    from controltac_il.io import write_json

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    staging = args.out.with_name(args.out.name + ".partial")
    staging.mkdir(parents=True, exist_ok=True)
    record = {"presses": str(args.presses.resolve()), "images": len(ds),
              "estimator": estimator_part(args, ds, staging), "generator": generator_part(args, staging)}
    write_json(staging / "calibration.json", record)
    (staging / "README.md").write_text(_card(record))
    for leftover in ("estimator.train_state", "generator.run"):
        shutil.rmtree(staging / leftover, ignore_errors=True)
    os.replace(staging, args.out)
    return record


def _card(r: dict) -> str:
    e, g = r["estimator"], r["generator"]
    axes = lambda v: ", ".join(f"{a} {x:.3f}" for a, x in zip(("Fx", "Fy", "Fz"), v))  # noqa: E731
    return (f"# Sensor calibration bundle\n\nFrom {r['images']} presses in `{r['presses']}`.\n\n"
            f"- estimator: {e['base']} ({e['base_hash']}) fine-tuned {e['steps']} steps on {e['train_images']} images; "
            f"MAE on {e['val_images']} held-out-pose images, N: before {axes(e['val_mae_before_n'])}; after "
            f"{axes(e['val_mae_after_n'])}\n"
            f"- generator: {g['base']} ({g['base_hash']}) fine-tuned: autoencoder {g['ae_steps']} steps, DiT "
            f"{g['dit_steps']} steps, peak LR {g['lr']}\n\nThe generator's error against the number of presses is "
            "measured on a held-out sensor by `python -m benchmarks.finetune`.\n")


def main(argv=None) -> int:
    """0 done, 1 stopped on a NaN / inf loss, 2 bad options or data, 130 Ctrl-C (state kept for --resume)."""
    args = parser().parse_args(argv)  # before the job's imports (torch): --help answers at once
    from controltac_il.training import run_cli


    def job() -> None:  # run_cli turns check's ValueError into one line and exit 2
        record = run(args, check(args))
        print(json.dumps({k: record[k] for k in ("images", "estimator", "generator")}, indent=2))
        print(f"wrote {args.out}")

    return run_cli(PROG, job)


if __name__ == "__main__":
    raise SystemExit(main())
