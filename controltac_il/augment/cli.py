"""``python -m controltac_il.augment``: build a ForceAugment cache. The settings flags are derived from
``ForceAugmentConfig`` (each field's default and help); only the I/O flags are written here."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.dataset import ForceAugment
from controltac_il.datasets.act_dataset import EpisodeDataset


def _default_text(value) -> str:
    if value is None:
        return ""
    shown = " ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value) if isinstance(value, tuple) else value
    return f" (default {shown})"


def add_config_flags(parser: argparse.ArgumentParser) -> None:
    """One ``--<field-name>`` flag per ForceAugmentConfig field the CLI exposes, with its default and help."""
    for f in dataclasses.fields(ForceAugmentConfig):
        cli = f.metadata.get("cli")
        if cli is None:
            continue
        default = list(f.default) if isinstance(f.default, tuple) else f.default
        parser.add_argument("--" + f.name.replace("_", "-"), default=default, dest=f.name,
                            help=f.metadata["help"] + _default_text(f.default), **cli)


def config_kwargs(args: argparse.Namespace) -> dict:
    """The ForceAugment keyword arguments of the parsed config flags."""
    out = {}
    for f in dataclasses.fields(ForceAugmentConfig):
        if f.metadata.get("cli") is not None:
            v = getattr(args, f.name)
            out[f.name] = tuple(v) if isinstance(v, list) else v
    return out


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m controltac_il.augment",
        description="Build a ForceAugment cache: generate every augmented tactile frame of a folder of ACT "
                    "episodes once (batched), with provenance. Resumable (re-run the same command) and "
                    "shardable (torchrun --nproc_per_node N -m controltac_il.augment ...).")
    p.add_argument("--dataset", required=True, type=Path, help="folder of episode_<i>.hdf5 files (read-only)")
    p.add_argument("--out", required=True, type=Path, help="cache folder to create or complete")
    add_config_flags(p)
    p.add_argument("--generator", default=None, help="generator checkpoint folder (default: shipped)")
    p.add_argument("--estimator", default=None, help="force estimator checkpoint (only for data without force labels)")
    p.add_argument("--device", default="cpu", help="torch device for the generator (default cpu)")
    return p


def _report(aug: ForceAugment, counts: dict) -> None:
    rate = counts["generated"] / counts["seconds"] if counts["seconds"] > 0 else float("nan")
    print(f"wrote {counts['chunks']} chunk(s), {counts['generated']} generated frames in "
          f"{counts['seconds']:.1f} s ({rate:.2f} frames/s) to {aug.cache_dir}")
    missing = aug.missing_chunks()
    if missing:
        print(f"{len(missing)} chunk(s) left to other ranks or a later run")
        return
    s = aug.summary()
    print(f"cache complete: {s['tactile_frames']} augmented tactile frames, {s['regenerated']} regenerated, "
          f"{s['clamped']} clamped, {s['skipped']} skipped (kept real), {s['no_contact']} without contact")


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    from controltac_il.generator import ForceGenerator

    estimator = None
    if args.estimator:
        from controltac_il.estimators import ForceEstimator

        estimator = ForceEstimator.from_pretrained(args.estimator)
    dataset = EpisodeDataset(args.dataset, chunk_size=1, cameras=[])
    aug = ForceAugment(dataset, ForceGenerator.from_pretrained(args.generator, device=args.device),
                       cache_dir=args.out, estimator=estimator, build="manual", progress=True,
                       **config_kwargs(args))
    _report(aug, aug.build_cache())
    return 0

