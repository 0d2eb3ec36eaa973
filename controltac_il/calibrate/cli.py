"""The command line of ``python -m controltac_il.calibrate`` (presses or recordings -> a bundle)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from controltac_il.calibrate import __doc__ as DOC
from controltac_il.cli import ArgumentParser
from controltac_il.calibrate.decision import MIN_GRASPS
from controltac_il.tactile.spec import IMAGE_SIDE_PX

PROG = "python -m controltac_il.calibrate"
RECORDING_FLAGS = ("lag", "stride", "size")  # --recordings only; their defaults are RecordingOptions'


def _lag(text: str):
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an int (frames) or 'auto', got {text!r}") from None


def parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog=PROG, description=DOC.split("\n\n")[0].split(": ", 1)[1])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--presses", type=Path, help="labelled frames in the FeelAnyForce layout (read-only)")
    src.add_argument("--recordings", type=Path,
                     help="a folder of recordings: <name>.mp4 or <name>/ frames, with <name>.csv (column fz, N, one row a frame)")
    p.add_argument("--out", type=Path, required=True, help="the bundle folder to write (new)")
    p.add_argument("--lag", type=_lag, default=None,
                   help="recordings: force log shift in frames, or 'auto' (default 0)")
    p.add_argument("--stride", type=int, default=None,
                   help="recordings: keep every n-th ramp frame (default 1)")
    p.add_argument("--size", type=int, nargs=2, default=None, metavar=("H", "W"),
                   help="recordings: frame size written (default 240 320, the GelSight Mini's)")
    p.add_argument("--base-generator", default="default",
                   help="generator to fine-tune: a shipped preset (default, fast, quality) or a folder (default: default)")
    p.add_argument("--base-estimator", default=None, help="estimator to calibrate (default: the shipped one)")
    p.add_argument("--estimator-method", choices=("auto", "adapter", "finetune"), default="auto",
                   help="adapter: a colour mix before the frozen network (few frames); finetune: the whole network; "
                        "auto (default): finetune from 500 labelled frames on")
    p.add_argument("--estimator-steps", type=int, default=None, help="estimator steps (default: 150 adapter, 1000 finetune)")
    p.add_argument("--ae-steps", type=int, default=600, help="generator autoencoder fine-tuning steps (default 600)")
    p.add_argument("--dit-steps", type=int, default=600, help="generator DiT fine-tuning steps (default 600)")
    p.add_argument("--lr", type=float, default=2e-4, help="peak learning rate of the generator's fine-tunes")
    p.add_argument("--batch", type=int, default=64, help="DiT batch (default 64)")
    p.add_argument("--val-fraction", type=float, default=0.2, help="grasps held out from the generator (default 0.2)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--device", default="cpu", help="where the generator fine-tunes: cpu (default) or cuda")
    p.add_argument("--resume", action="store_true", help="continue a stopped run in OUT.partial")
    return p


def check(args: argparse.Namespace) -> None:
    """ValueError naming the flag for a bad option or output; fills the recordings' defaults."""
    from controltac_il.calibrate.recordings import RecordingOptions

    given = [f for f in RECORDING_FLAGS if getattr(args, f) is not None]
    if args.presses is not None and given:
        raise ValueError(f"--{given[0]}: reads recordings, used only with --recordings (presses are labelled frames)")
    for name in RECORDING_FLAGS:
        setattr(args, name, getattr(RecordingOptions(), name) if getattr(args, name) is None else getattr(args, name))
    for flag, value, low in (("--estimator-steps", args.estimator_steps or 1, 1), ("--ae-steps", args.ae_steps, 0),
                             ("--dit-steps", args.dit_steps, 1), ("--batch", args.batch, 1), ("--stride", args.stride, 1)):
        if value < low:
            raise ValueError(f"{flag}: expected an int >= {low}, got {value}")
    lo, hi = IMAGE_SIDE_PX
    if not all(lo <= v <= hi for v in args.size):
        raise ValueError(f"--size: expected H W in pixels, each in [{lo}, {hi}], got {args.size[0]} {args.size[1]}")
    if not 0 < args.val_fraction < 1:
        raise ValueError(f"--val-fraction: expected a share in (0, 1), got {args.val_fraction}")
    if not 0 < args.lr < float("inf"):
        raise ValueError(f"--lr: expected a finite learning rate > 0, got {args.lr}")
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads: expected an int >= 1, got {args.threads}")
    from controltac_il.training import device_problem

    problem = device_problem(args.device)
    if problem:
        raise ValueError(problem)
    if args.out.exists():
        raise ValueError(f"--out: {args.out} exists; a bundle is written to a new folder")
    staging = args.out.with_name(args.out.name + ".partial")
    if staging.exists() and not args.resume:
        raise ValueError(f"--out: {staging} holds a stopped run: pass --resume to continue it, or delete it")
    src, flag = (args.presses, "--presses") if args.presses is not None else (args.recordings, "--recordings")
    if not src.is_dir():
        raise ValueError(f"{flag}: {src} is not a folder")
    check_bases(args)


def check_bases(args: argparse.Namespace) -> None:
    """Both base models load (checksums included) before anything is written or fitted; ValueError naming the flag."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.generator import ForceGenerator

    for flag, load, name in (("--base-estimator", ForceEstimator.from_pretrained, args.base_estimator),
                             ("--base-generator", ForceGenerator.from_pretrained, args.base_generator)):
        try:
            load(name)
        except (ValueError, OSError) as exc:
            raise ValueError(f"{flag}: {' '.join(str(exc).split())}") from None


def load(args: argparse.Namespace):
    """(the presses dataset, the recordings' summary or None); recordings are written as presses into the staging
    folder first. ValueError naming the flag or file."""
    from controltac_il.calibrate.recordings import RecordingOptions, recordings_to_presses
    from controltac_il.tactile.dataset import load_dataset

    source, root = None, args.presses
    if args.recordings is not None:
        root = args.out.with_name(args.out.name + ".partial") / "presses"
        opts = RecordingOptions(size=tuple(args.size), lag=args.lag, stride=args.stride)
        source = {"recordings": str(args.recordings.resolve()), "lag": args.lag, "stride": args.stride,
                  "per_recording": recordings_to_presses(args.recordings, root, opts)}
    try:
        ds = load_dataset(root)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--presses: not a presses folder in the FeelAnyForce layout ({' '.join(str(exc).split())})") from None
    grasps = len(ds.pose_groups())
    if grasps < MIN_GRASPS:
        flag, given = ("--presses", root) if args.recordings is None else ("--recordings", args.recordings)
        raise ValueError(f"{flag}: {given} holds {grasps} grasp{'' if grasps == 1 else 's'} (contact poses); at least "
                         f"{MIN_GRASPS} are needed (each is held out once to decide whether the estimator is used)")
    return ds, source


def main(argv=None) -> int:
    """0 done, 1 stopped on a NaN / inf loss, 2 bad options or data, 130 Ctrl-C (state kept for --resume)."""
    args = parser().parse_args(argv)  # before the job's imports (torch): --help answers at once
    from controltac_il.training import run_cli

    def job() -> None:  # run_cli turns a ValueError into one line and exit 2
        from controltac_il.calibrate.bundle import run
        from controltac_il.calibrate.report import table

        check(args)
        record = run(args, *load(args))
        print(table(record))
        print(json.dumps({k: record[k] for k in ("images", "source")}, indent=2))
        print(f"wrote {args.out} (report: {args.out / 'report.png'})")

    return run_cli(PROG, job)
