#!/usr/bin/env python
"""Train an ACT policy on a folder of episodes (episode_<i>.hdf5), optionally with ForceAugment.

    python train_act.py                                   # embedded default: demos from the MuJoCo scene
    python train_act.py --dataset DEMOS --preset cpu --steps 2000 --out runs/act
    python train_act.py --dataset DEMOS --augment force --copies 2 --out runs/act_aug
    torchrun --nproc_per_node 2 train_act.py --dataset DEMOS --out runs/act   # data parallel (gloo on CPU)

Writes OUT/last (resumable, --resume), OUT/best (lowest validation L1) and OUT/train_log.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", type=Path, default=None,
                   help="folder of episode_<i>.hdf5 files (default: collect/reuse the embedded MuJoCo demos)")
    p.add_argument("--out", type=Path, default=Path("runs/act"), help="output folder (default: runs/act)")
    p.add_argument("--preset", choices=("cpu", "gpu"), default="cpu",
                   help="cpu: small CNN, dim 128 (minutes on 2 cores); gpu: ResNet-18, dim 512 (the paper's ACT)")
    p.add_argument("--steps", type=int, default=2000, help="optimiser steps (default 2000)")
    p.add_argument("--batch-size", type=int, default=16, help="samples per step and process (default 16)")
    p.add_argument("--chunk-size", type=int, default=20, help="actions per chunk N_a (default 20, the paper's)")
    p.add_argument("--val-every", type=int, default=250, help="validate every N steps (default 250)")
    p.add_argument("--val-fraction", type=float, default=0.1, help="episodes held out for validation (default 0.1)")
    p.add_argument("--augment", choices=("none", "force"), default="none",
                   help="force: add ForceAugment copies of every training episode (generated tactile frames)")
    p.add_argument("--copies", type=int, default=2, help="ForceAugment copies per episode, 1-9 (default 2)")
    p.add_argument("--generator", type=Path, default=None, help="generator checkpoint (default: the shipped one)")
    p.add_argument("--demos", type=int, default=20, help="episodes collected for the embedded default (default 20)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of initialisation, split and sampling (default 0)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads per process (default: torch's)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        summary = run(args)
    except (ValueError, FileNotFoundError) as exc:  # bad options, data or checkpoint: CheckpointError is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if os.environ.get("RANK", "0") == "0":
        print(json.dumps(summary, indent=2))
    return 0


def run(args: argparse.Namespace) -> dict:
    import torch

    from controltac_il.app.train import train_act
    from policies.act.training import TrainConfig

    if args.threads:
        torch.set_num_threads(args.threads)
    train_config = TrainConfig(steps=args.steps, batch_size=args.batch_size, val_every=args.val_every,
                               num_workers=args.workers, seed=args.seed)
    return train_act(args.out, args.dataset, demos=args.demos, preset=args.preset, train_config=train_config,
                     copies=args.copies if args.augment == "force" else 0, generator=args.generator,
                     val_fraction=args.val_fraction, chunk_size=args.chunk_size, resume=args.resume)


if __name__ == "__main__":
    sys.exit(main())
