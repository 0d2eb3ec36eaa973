"""Train an ACT policy on a folder of episodes (episode_<i>.hdf5) or a LeRobot v3.0 folder, optionally with
ForceAugment.

    python train_act.py                                   # or controltac-train; embedded default: MuJoCo demos
    python train_act.py --dataset DEMOS --preset cpu --steps 2000 --out runs/act
    python train_act.py --dataset DEMOS --augment force --copies 2 --out runs/act_aug
    torchrun --nproc_per_node 2 train_act.py --dataset DEMOS --out runs/act   # data parallel (gloo on CPU)

Writes OUT/last (resumable, --resume), OUT/best (lowest validation L1) and OUT/train_log.json. An OUT that
holds a previous run needs --resume (continue it) or --overwrite (replace it; only what this tool wrote is
removed); files of the user's are never replaced. Ctrl-C saves the current step to OUT/last before exiting;
a NaN / inf loss stops the run (exit 1) with OUT/last at the last good step. Bad options or data: one line
on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from controltac_il.cli import ArgumentParser, key_value_pairs
from envs.config import DEMO_EPISODES


COPIES = 2  # ForceAugment copies per episode by default (the verdict's fa2)


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", type=Path, default=None,
                   help="folder of episode_<i>.hdf5 files, or a LeRobot v3.0 folder (observation.state, action; "
                        "tactile cameras are those named gelsight / tactile / digit, their force labels "
                        "observation.<camera>.force) (default: collect/reuse the embedded MuJoCo demos)")
    p.add_argument("--tactile-keys", nargs="+", action="extend", default=None, metavar="KEY",
                   help="LeRobot folder: its tactile cameras, by name (gs_left) or key (observation.images.gs_left) "
                        "(default: cameras named gelsight / tactile / digit)")
    p.add_argument("--force-keys", nargs="+", action="extend", default=None, metavar="TACTILE_KEY=FORCE_KEY",
                   help="LeRobot folder: the force label of each tactile camera (default: observation.<camera>.force)")
    p.add_argument("--background-image", nargs="+", action="extend", default=None, metavar="TACTILE_KEY=PNG",
                   help="the no-contact image of a tactile sensor at rest (an RGB PNG at its frames' size; a "
                        "LeRobot camera's name or key, or an episode folder's sensor name), its background in every "
                        "episode and in the checkpoint (default: the episodes' recorded one, else estimated per "
                        "episode from its frames, which needs episodes that start out of contact)")
    p.add_argument("--out", type=Path, default=Path("runs/act"), help="output folder (default: runs/act)")
    p.add_argument("--preset", choices=("cpu", "gpu"), default="cpu",
                   help="cpu: small CNN, dim 128 (minutes on 2 cores); gpu: ResNet-18, dim 512 (the paper's ACT) "
                        "(default cpu)")
    p.add_argument("--steps", type=int, default=2000, help="optimiser steps (default 2000)")
    p.add_argument("--batch-size", type=int, default=16, help="samples per step and process (default 16)")
    p.add_argument("--chunk-size", type=int, default=20, help="actions per chunk N_a (default 20, the paper's)")
    p.add_argument("--val-every", type=int, default=250, help="validate every N steps (default 250)")
    p.add_argument("--val-fraction", type=float, default=0.1, help="episodes held out for validation (default 0.1)")
    p.add_argument("--augment", choices=("none", "force"), default="none",
                   help="force: add ForceAugment copies of every training episode (generated tactile frames) "
                        "(default none)")
    p.add_argument("--copies", type=int, default=None,
                   help=f"ForceAugment copies per episode, 1-9 (default {COPIES}; with --augment force only)")
    p.add_argument("--generator", default=None,
                   help="with --augment force: a shipped preset (default, quality; fast is for speed checks, its "
                        "frames err more than the unchanged reference), a checkpoint folder, or a calibration bundle, "
                        "whose estimator reads unlabelled frames where calibration says it may (default: default)")
    p.add_argument("--demos", type=int, default=None,
                   help=f"episodes collected for the embedded default, without --dataset (default {DEMO_EPISODES})")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last (same dataset and options)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous run in OUT (only the last/, best/ and train_log.json this tool wrote)")
    p.add_argument("--checkpoint-every", type=int, default=500,
                   help="write OUT/last (resumable) every N steps, and at the end and on Ctrl-C (default 500)")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of initialisation, split and sampling (default 0)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads per process (default: torch's)")
    return p.parse_args(argv)


# ACTTrainConfig field -> the flag that sets it (validation errors name the flag)
FLAGS = {"steps": "--steps", "batch_size": "--batch-size", "val_every": "--val-every", "save_every": "--checkpoint-every",
         "num_workers": "--workers", "seed": "--seed"}


# the data options -> the flags that set them
DATA_FLAGS = {"tactile_keys": "--tactile-keys", "force_keys": "--force-keys", "background_images": "--background-image"}


def augment_copies(args: argparse.Namespace) -> int:
    """ForceAugment copies per episode: --copies (default COPIES) with --augment force, else 0."""
    if args.augment != "force":
        return 0
    return COPIES if args.copies is None else args.copies


def check_args(args: argparse.Namespace):
    """The run's ACTTrainConfig; ValueError (one line naming the flag and the expected form) for a bad option."""
    from controltac_il.config import one_line
    from controltac_il.app import ACTTrainConfig
    from controltac_il.datasets.background import read_background_image

    if args.resume and args.overwrite:
        raise ValueError("--resume and --overwrite exclude each other: continue the run in --out, or replace it")
    if not 0.0 <= args.val_fraction < 1.0:
        raise ValueError(f"--val-fraction must be in [0, 1) (a share of the episodes), got {args.val_fraction}")
    if args.demos is not None and args.dataset is not None:
        raise ValueError(f"--demos {args.demos}: the embedded demos' count, not used with --dataset")
    args.demos = DEMO_EPISODES if args.demos is None else args.demos
    for flag, value, low in (("--chunk-size", args.chunk_size, 1), ("--demos", args.demos, 1),
                             ("--threads", args.threads, 1)):
        if value is not None and value < low:
            raise ValueError(f"{flag} must be an integer >= {low}, got {value}")
    if args.copies is not None and args.augment != "force":
        raise ValueError(f"--copies {args.copies}: ForceAugment's copies per episode, used only with --augment force")
    if args.generator is not None and args.augment != "force":
        raise ValueError(f"--generator {args.generator}: ForceAugment's generator, used only with --augment force")
    if args.augment == "force" and not 1 <= augment_copies(args) <= 9:
        raise ValueError(f"--copies must be in 1..9 (ForceAugment copies per episode), got {args.copies}")
    if args.dataset is not None and not args.dataset.is_dir():
        raise ValueError(f"--dataset {args.dataset}: episode folder not found")
    options = data_options(args) or {}  # the KEY=VALUE flags' form checked
    if (args.tactile_keys or args.force_keys) and not (args.dataset and (args.dataset / "meta" / "info.json").is_file()):
        raise ValueError("--tactile-keys / --force-keys: only with a LeRobot v3.0 --dataset (a folder with "
                         "meta/info.json)")
    for path in options.get("background_images", {}).values():
        read_background_image(path, field="--background-image")  # before any slow work
    try:
        return ACTTrainConfig(steps=args.steps, batch_size=args.batch_size, val_every=args.val_every,
                           save_every=args.checkpoint_every, num_workers=args.workers, seed=args.seed)
    except ValueError as exc:  # pydantic: one line naming the flag
        raise ValueError(one_line(exc, FLAGS)) from None


def main(argv=None) -> int:
    """0 done, 1 stopped on a NaN / inf loss, 2 bad options or data (one line), 130 Ctrl-C (state saved)."""
    args = parse_args(argv)  # before the job's imports (torch): --help answers at once
    from controltac_il.training import run_cli


    def job() -> None:  # run_cli turns check_args' ValueError into one line and exit 2
        summary = run(args, check_args(args))
        if os.environ.get("RANK", "0") == "0":
            print(json.dumps(summary, indent=2))

    return run_cli("train_act.py", job)


def run(args: argparse.Namespace, train_config=None) -> dict:
    import torch

    from controltac_il.app.train import train_act

    if args.threads:
        torch.set_num_threads(args.threads)
    train_config = train_config or check_args(args)
    try:
        return train_act(args.out, args.dataset, demos=args.demos, preset=args.preset, train_config=train_config,
                         copies=augment_copies(args), generator=args.generator,
                         val_fraction=args.val_fraction, chunk_size=args.chunk_size, resume=args.resume,
                         overwrite=args.overwrite, data_options=data_options(args))
    except ValueError as exc:  # a data option's error ("tactile_keys: ...") named by its flag
        field, _, rest = str(exc).partition(": ")
        if field in DATA_FLAGS:
            raise ValueError(f"{DATA_FLAGS[field]}: {rest}") from exc
        raise


def data_options(args: argparse.Namespace) -> dict | None:
    """--tactile-keys / --force-keys / --background-image as ``load_training_data``'s data options (None: the
    defaults)."""
    keys = {}
    if args.tactile_keys:
        keys["tactile_keys"] = list(args.tactile_keys)
    if args.force_keys:
        keys["force_keys"] = key_value_pairs("--force-keys", args.force_keys, "TACTILE_KEY=FORCE_KEY")
    if args.background_image:
        keys["background_images"] = key_value_pairs("--background-image", args.background_image, "TACTILE_KEY=PNG")
    return keys or None

