"""Train a force estimator on a tactile dataset folder (FeelAnyForce layout).

    python -m controltac_il.estimators.train --data DATA_DIR --out runs/estimator
    python -m controltac_il.estimators.train --data DATA_DIR --out runs/estimator --resume

The checkpoint folder (model.safetensors + config.json + model_card.json with the weights' hash +
README.md) is rewritten atomically at every checkpoint; the resumable optimiser state lives beside it in ``<out>.train_state/``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from controltac_il.estimators.config import EstimatorConfig
from controltac_il.estimators.data import load_arrays, native_no_contact, split_by_pose
from controltac_il.estimators.fit import TrainConfig, fit


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
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
    return p


def model_card(data: Path, n_train: int, n_val: int, history: list, cfg: EstimatorConfig, train: TrainConfig) -> str:
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
        "- Valid range: the training forces' range (sensor-model data: Fz 0.5-11 N, |Fx|, |Fy| <= 1 N); "
        "real sensors need retraining or fine-tuning on their own frames.\n"
    )


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    import torch

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
    if not 0 <= args.no_contact_fraction < 1:
        raise ValueError(f"--no-contact-fraction must be in [0, 1), got {args.no_contact_fraction}")
    n_empty = int(round(len(x) * args.no_contact_fraction / (1 - args.no_contact_fraction)))
    x = np.concatenate([x, native_no_contact(ds, n_empty, size, seed=args.seed)])
    f = np.concatenate([f, np.zeros((n_empty, 3), np.float32)])
    val = load_arrays(val_ds, val_idx, size=size, progress=True) if (val_idx is None or val_idx) else None
    train = TrainConfig(steps=args.steps, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                        checkpoint_every=args.checkpoint_every, eval_every=args.checkpoint_every)
    cfg = EstimatorConfig(input_height=size[0], input_width=size[1])
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
    empty = np.full((1, *size, 3), 127, np.uint8)
    print(f"no-contact frame: raw network reading {np.round(est.predict(empty, gate=False)[0], 3).tolist()} N "
          "(predict() gates it to 0)")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
