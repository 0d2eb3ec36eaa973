"""Train a force estimator on a tactile dataset folder (FeelAnyForce layout).

    python -m controltac_il.estimators.train --data DATA_DIR --out runs/estimator
    python -m controltac_il.estimators.train --data DATA_DIR --out runs/estimator --resume

The checkpoint folder (model.safetensors + config.json + model_card.json with the weights' hash +
README.md) is rewritten atomically at every checkpoint; the resumable optimiser state lives beside it in ``<out>.train_state/``.
An --out that holds a previous run needs --resume (continue) or --overwrite (replace; only the files this tool
writes there); a folder of the user's is never replaced. A NaN / inf loss stops the run (exit 1) with the last
saved state kept; Ctrl-C saves the current step before exiting (exit 130). Bad options or data: one line on
stderr, exit 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from controltac_il.cli import ArgumentParser
from controltac_il.config import one_line
from controltac_il.estimators.config import EstimatorConfig, EstimatorTrainConfig
from controltac_il.estimators.data import load_arrays, native_no_contact, split_by_pose
from controltac_il.outputs import claim_output, own_checkpoint, own_json, own_safetensors
from controltac_il.tactile.residual import OFFSET


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="python -m controltac_il.estimators.train",
        description="Train the compact CNN force estimator (tactile residual -> [Fx, Fy, Fz] N) on a "
        "dataset folder written by controltac_il.tactile.dataset.write_dataset (or a FeelAnyForce-style "
        "recording: manifest.csv + background.png + images). Whole contact poses are held out for validation.",
    )
    p.add_argument("--data", type=Path, required=True, help="training dataset folder (manifest.csv, background.png, images/)")
    p.add_argument("--out", type=Path, required=True, help="checkpoint folder to write (replaced atomically)")
    p.add_argument("--val-data", type=Path, default=None, help="separate validation dataset (default: hold out poses of --data)")
    p.add_argument("--val-fraction", type=float, default=0.1, help="fraction of each object's poses held out for validation (default 0.1)")
    p.add_argument("--no-contact-fraction", type=float, default=0.05,
                   help="share of added no-contact frames (label 0 N) in the training set (default 0.05)")
    p.add_argument("--input-size", type=int, nargs=2, default=(64, 80), metavar=("H", "W"),
                   help="network input size; residuals are resized to it (default 64 80)")
    p.add_argument("--steps", type=int, default=3000, help="AdamW updates (default 3000)")
    p.add_argument("--batch-size", type=int, default=64, help="images per update (default 64)")
    p.add_argument("--lr", type=float, default=2e-3, help="peak learning rate, cosine decay (default 2e-3)")
    p.add_argument("--seed", type=int, default=0, help="seed for weights, sampling and the split (default 0)")
    p.add_argument("--checkpoint-every", type=int, default=250, help="write checkpoint + resume state every N steps (default 250)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--resume", action="store_true", help="continue from <out>.train_state/")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous run's --out and <out>.train_state/ (only files this tool wrote)")
    return p


PROG = "python -m controltac_il.estimators.train"
# EstimatorTrainConfig / EstimatorConfig field -> the flag that sets it (validation errors name the flag)
FLAGS = {"steps": "--steps", "batch_size": "--batch-size", "lr": "--lr", "min_lr": "--lr", "seed": "--seed",
         "checkpoint_every": "--checkpoint-every", "eval_every": "--checkpoint-every",
         "input_height": "--input-size", "input_width": "--input-size"}


def _own_state_dir(path: Path) -> str | None:
    """None when ``path`` is a resume state folder this tool wrote (state.json + state.safetensors only)."""
    if not path.is_dir():
        return "not a folder"
    names = sorted(x.name for x in path.iterdir())
    if names != ["state.json", "state.safetensors"]:
        return "it holds files other than this tool's state.json and state.safetensors"
    return own_json("step", "train", "model")(path / "state.json") or own_safetensors("model.", "optimizer.", "rng")(
        path / "state.safetensors")


def outputs(out: Path) -> dict:
    """What a run writes beside ``out`` (names in its parent), each with how it is recognised as this tool's own."""
    return {out.name: own_checkpoint(("config.json", "model.safetensors", "model_card.json", "README.md"),
                                     lambda c: c.get("input_kind") == "residual"),
            out.name + ".train_state": _own_state_dir}


def check_args(args: argparse.Namespace) -> tuple[EstimatorTrainConfig, EstimatorConfig]:
    """The run's configs; ValueError (one line naming the flag and the expected form) for a bad option or --out."""
    try:
        train = EstimatorTrainConfig(steps=args.steps, batch_size=args.batch_size, lr=args.lr, min_lr=min(2e-5, args.lr),
                            seed=args.seed, checkpoint_every=args.checkpoint_every, eval_every=args.checkpoint_every)
        cfg = EstimatorConfig(input_height=args.input_size[0], input_width=args.input_size[1])
    except ValueError as exc:  # pydantic: one line naming the flag
        raise ValueError(one_line(exc, FLAGS)) from None
    for flag, value in (("--val-fraction", args.val_fraction), ("--no-contact-fraction", args.no_contact_fraction)):
        if not 0 <= value < 1:
            raise ValueError(f"{flag} must be in [0, 1) (a share), got {value}")
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be an integer >= 1, got {args.threads}")
    for flag, folder in (("--data", args.data), ("--val-data", args.val_data)):
        if folder is not None and not (folder / "manifest.csv").is_file():
            raise ValueError(f"{flag} {folder}: not a tactile dataset folder (no manifest.csv there)")
    if args.resume and args.overwrite:
        raise ValueError("--resume and --overwrite exclude each other: continue the run in --out, or replace it")
    state_dir = args.out.with_name(args.out.name + ".train_state")
    if args.resume and not (state_dir / "state.json").is_file():
        raise ValueError(f"--resume: no training state to continue in {state_dir}")
    claim_output(args.out.parent, outputs(args.out), resume=args.resume, overwrite=args.overwrite,
                 tool=PROG, label=str(args.out))
    return train, cfg


def model_card(data: Path, n_train: int, n_val: int, history: list, cfg: EstimatorConfig, train: EstimatorTrainConfig) -> str:
    from controltac_il.tactile.dataset import FZ_RANGE, SHEAR_MAX  # here: python -m runs that module on its own

    last = history[-1] if history else None
    mae = "n/a" if last is None else ", ".join(f"{a} {v:.3f} N" for a, v in zip(("Fx", "Fy", "Fz"), last["val_mae"]))
    return (
        "# Force estimator checkpoint\n\n"
        "Compact CNN (four stride-2 conv stages, mean+max pooling, two-layer head) trained from scratch.\n\n"
        f"- Input: tactile residual uint8 (N, H, W, 3) (image - background + 127), resized to "
        f"{cfg.input_height}x{cfg.input_width}.\n"
        "- Output: [Fx, Fy, Fz] in N, sensor frame (x along columns, y up the rows, Fz > 0 pressing).\n"
        f"- Training data: `{data.name}` ({n_train} frames incl. no-contact frames labelled 0 N), "
        f"{train.steps} AdamW steps, batch {train.batch_size}, lr {train.lr} cosine, seed {train.seed}.\n"
        f"- Validation (held-out contact poses, {n_val} frames) MAE: {mae}.\n"
        f"- Valid range: the training forces' range (sensor-model data: Fz {FZ_RANGE[0]:g}-{FZ_RANGE[1]:g} N, "
        f"|Fx|, |Fy| <= {SHEAR_MAX:g} N); "
        "real sensors need retraining or fine-tuning on their own frames.\n"
    )


def main(argv=None) -> int:
    """The CLI: 0 done, 1 stopped on a NaN / inf loss, 2 bad options or data (one line), 130 Ctrl-C (state saved)."""
    args = build_parser().parse_args(argv)
    try:
        train, cfg = check_args(args)
    except (ValueError, OSError) as exc:  # OutputInUse is a ValueError; an output folder we cannot read or clear
        print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    from controltac_il.training import run_cli

    return run_cli(PROG, lambda: run(args, train, cfg))


def run(args: argparse.Namespace, train: EstimatorTrainConfig, cfg: EstimatorConfig) -> None:
    import torch

    from controltac_il.estimators.fit import fit
    from controltac_il.tactile.dataset import load_dataset

    if args.threads:
        torch.set_num_threads(args.threads)
    size = tuple(args.input_size)
    ds = load_dataset(args.data)
    if args.val_data is not None:
        train_idx, val_idx, val_ds = list(range(len(ds))), None, load_dataset(args.val_data)
    else:
        train_idx, val_idx = split_by_pose(ds.pose_groups(), args.val_fraction, seed=args.seed)
        val_ds = ds
    x, f = load_arrays(ds, train_idx, size=size, progress=True)
    n_empty = int(round(len(x) * args.no_contact_fraction / (1 - args.no_contact_fraction)))
    x = np.concatenate([x, native_no_contact(ds, n_empty, size, seed=args.seed)])
    f = np.concatenate([f, np.zeros((n_empty, 3), np.float32)])
    val = load_arrays(val_ds, val_idx, size=size, progress=True) if (val_idx is None or val_idx) else None
    state_dir = args.out.with_name(args.out.name + ".train_state")
    n_val = 0 if val is None else len(val[0])

    def save(est, step, history=None):
        est.save(args.out, card=model_card(args.data, len(x), n_val, history or [], est.config, train))

    est, history = fit(x, f, cfg, train, val=val, state_dir=state_dir, resume=args.resume,
                       on_checkpoint=save)
    save(est, train.steps, history)
    if history:
        h = history[-1]
        print(f"step {h['step']}: validation MAE Fx {h['val_mae'][0]:.3f} N, Fy {h['val_mae'][1]:.3f} N, "
              f"Fz {h['val_mae'][2]:.3f} N (mean {h['val_mae_mean']:.3f} N)")
    empty = np.full((1, *size, 3), OFFSET, np.uint8)
    print(f"no-contact frame: raw network reading {np.round(est.predict(empty, gate=False)[0], 3).tolist()} N "
          "(predict() gates it to 0)")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    raise SystemExit(main())
