"""``python -m controltac_il.augment``: build a ForceAugment cache. The settings flags are derived from
``ForceAugmentConfig`` (each field's default and help); only the I/O flags are written here.

Every validation error (a flag's value, the dataset, the checkpoints, a cache that does not provably match)
is one line on stderr naming the flag and what it expects, exit status 2; a traceback means a bug. Ctrl-C
stops with status 130; re-running the same command resumes the build."""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path

from typing import TYPE_CHECKING

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.cli import guard, key_value_pairs
from controltac_il.io import check_apart

if TYPE_CHECKING:  # the job's modules (torch, h5py) are imported inside it: --help stays light
    from controltac_il.augment.dataset import ForceAugment

PROG = "python -m controltac_il.augment"
# settings given as KEY=VALUE pairs: their flag and its form
MAP_FLAGS = {"force_keys": ("--force-keys", "TACTILE_KEY=FORCE_KEY"), "background_images": ("--background-image",
                                                                                         "TACTILE_KEY=PNG")}


class UsageError(ValueError):
    """A validation error of the command line: ``flag`` and the one-line message, shown as ``FLAG: MESSAGE``."""

    def __init__(self, flag: str | None, message: str):
        super().__init__(f"{flag}: {message}" if flag else message)
        self.flag = flag


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's errors, as one line (its usage block is what --help is for)
        raise UsageError(None, f"{message} (see --help)")


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
    p = _Parser(
        prog=PROG,
        description="Augment a dataset's touch. A folder of ACT episodes: build its ForceAugment cache (every "
                    "augmented tactile frame generated once, batched, with provenance) into --out. A LeRobot v3.0 "
                    "folder: write --out as a LeRobot v3.0 folder holding the original episodes, then --copies "
                    "augmented copies of each (regenerated tactile frames, per-frame provenance features "
                    "augment.*, new meta and stats), ready for lerobot-train. Resumable (re-run the same command) "
                    "and shardable (torchrun --nproc_per_node N -m controltac_il.augment ...).")
    p.add_argument("--dataset", required=True, type=Path,
                   help="folder of episode_<i>.hdf5 files, or a LeRobot v3.0 dataset folder (meta/info.json; its "
                        "tactile cameras are those named gelsight / tactile / digit unless --tactile-keys names them, "
                        "as for train_act.py); read-only")
    p.add_argument("--force-keys", nargs="+", action="extend", default=None, metavar="TACTILE_KEY=FORCE_KEY",
                   help="the force label [Fx, Fy, Fz] N of each tactile key (for a LeRobot folder, or its camera's "
                        "name), e.g. observation.images.gelsight_left=observation.gelsight_left.force (default: "
                        "observation.<camera>.force where a LeRobot folder has it, else our layout's rule; unlabelled "
                        "keys use the estimator)")
    p.add_argument("--background-image", nargs="+", action="extend", default=None, metavar="TACTILE_KEY=PNG",
                   help="the no-contact image of a tactile sensor at rest (an RGB PNG, or JPEG, at the frames' "
                        "size, e.g. gelsight_left=rest_left.png), used for every episode: for a LeRobot folder (which "
                        "records no background) whose episodes start in contact (default: the episodes' recorded "
                        "background, else each episode's estimated from its own no-contact frames)")
    p.add_argument("--out", required=True, type=Path,
                   help="ACT episodes: the cache folder to create or complete. LeRobot: the augmented dataset folder "
                        "to write (new or empty; written under OUT.partial and renamed when complete)")
    add_config_flags(p)
    p.add_argument("--generator", default=None,
                   help="generator: a shipped preset (default; quality: lowest error, slower; fast: the fastest, "
                        "but on the pairs ForceAugment asks for its frames err more than the unchanged reference, "
                        "docs/generator.md: for speed checks, not training data), a checkpoint folder, or a "
                        "calibration bundle (python -m controltac_il.calibrate; its estimator too) (default: default)")
    p.add_argument("--estimator", default=None, help="force estimator checkpoint (only for data without force labels)")
    p.add_argument("--pose-adapter", default=None,
                   help="with --pose-offset: the stage-2 pose adapter folder (default: pose, shipped for the default)")
    p.add_argument("--device", default="cpu", help="torch device for the generator (default cpu)")
    p.add_argument("--video-round-trip", action="store_true",
                   help="LeRobot: decode every re-encoded tactile video back and report the codec's round trip error "
                        "(MSE, PSNR of the regenerated frames) in the output's record; costs one decode per re-encoded "
                        "video (default off; data and videos written are the same)")
    p.add_argument("--export-workers", type=int, default=None, metavar="N",
                   help="LeRobot: processes encoding output episodes' videos in parallel, each owning whole episodes "
                        "(default: 1; on a machine with many cores and the generator on a GPU, about cores - 2)")
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


def _write(aug: ForceAugment, out: Path, root: Path, round_trip: bool, workers: int) -> dict:
    from controltac_il.augment.provenance import StaleCacheError, chunk_done
    from controltac_il.lerobot import LeRobotFolder, write_lerobot

    try:
        # every feature (aug reads the tactile ones alone); decoder threads: nothing forks while writing
        return write_lerobot(aug, LeRobotFolder(root, video_threads=0), out, chunk_done=chunk_done,
                             round_trip=round_trip, export_workers=workers)
    except ValueError as exc:
        if isinstance(exc, StaleCacheError):
            raise
        raise _field_error(exc, "--dataset") from exc


def _report_lerobot(out: Path, counts: dict) -> None:
    if not counts["published"]:
        print(f"wrote {counts['episodes']} episode(s) of {out}; the other ranks' share or a later run finishes it")
        return
    m = counts["marker"]
    if counts.get("already"):
        print(f"{out} already holds this augmented dataset ({m['episodes']['written']} episodes); nothing to do")
        return
    mse = m["video_round_trip_mse"]
    codec = "" if mse is None else f"; video round trip MSE {mse:.2f} (PSNR {m['video_round_trip_psnr_db']:.1f} dB)"
    print(f"wrote {out}: {m['episodes']['written']} episodes ({m['episodes']['source']} original + "
          f"{m['episodes']['copies']} copies of each), {m['frames']} frames, {m['regenerated_frames']} tactile "
          f"images regenerated{codec}")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _field_error(exc: Exception, default_flag: str) -> UsageError:
    """A ValueError of the config or the wrapper ("<field>: ...") as the error of that field's flag."""
    text = " ".join(str(exc).split())
    m = re.match(r"^(\w+): (.*)$", text)
    fields = {f.name for f in dataclasses.fields(ForceAugmentConfig) if f.metadata.get("cli") is not None}
    if m and m[1] in fields:
        return UsageError(_flag(m[1]), m[2])
    if m and m[1] in MAP_FLAGS:
        return UsageError(MAP_FLAGS[m[1]][0], m[2])
    if m and m[1] in ("dataset", "root"):
        return UsageError("--dataset", m[2])
    if m and m[1] == "out":
        return UsageError("--out", m[2])
    return UsageError(default_flag, text)


def _setup(args) -> ForceAugment:
    """The ForceAugment of the parsed flags; UsageError naming the flag for anything invalid."""
    from controltac_il.augment.dataset import ForceAugment
    from controltac_il.augment.provenance import StaleCacheError

    if args.export_workers is not None and args.export_workers < 1:
        raise UsageError("--export-workers", f"expected an int >= 1 (processes writing output episodes), got "
                                             f"{args.export_workers}")
    kwargs = config_kwargs(args)
    if args.pose_adapter is not None and not kwargs.get("pose_offset"):
        raise UsageError("--pose-adapter", "the adapter that moves the contact, used only with --pose-offset")
    args.pose_adapter = args.pose_adapter or "pose"
    if kwargs["copies"] < 1:
        raise UsageError("--copies", f"expected an int >= 1 (copy 0 is the real data: a cache of 0 copies holds "
                                     f"nothing), got {kwargs['copies']}")
    try:
        ForceAugmentConfig(**kwargs)
    except ValueError as exc:
        raise _field_error(exc, "--copies") from exc
    if not args.dataset.is_dir():
        what = "does not exist" if not args.dataset.exists() else "is not a folder"
        raise UsageError("--dataset", f"expected a folder of episode_<i>.hdf5 files or a LeRobot v3.0 folder; "
                                      f"{args.dataset} {what}")
    kwargs.update(_pairs(args))
    lerobot = args.lerobot = (args.dataset / "meta" / "info.json").is_file()
    lerobot_only = [f for f, given in (("--video-round-trip", args.video_round_trip),
                                       ("--export-workers", args.export_workers is not None)) if given]
    if lerobot_only and not lerobot:
        raise UsageError(lerobot_only[0], "writes a LeRobot folder's output; --dataset holds ACT episodes (a cache)")
    args.export_workers = args.export_workers or 1
    if lerobot:
        from controltac_il.lerobot import check_destination

        try:
            check_destination(args.dataset, args.out)
        except ValueError as exc:
            raise _field_error(exc, "--out") from exc
        features = _lerobot_defaults(args.dataset, kwargs)
    elif args.out.exists() and not args.out.is_dir():
        raise UsageError("--out", f"expected a cache folder (new, empty, or a cache of these settings); "
                                  f"{args.out} is a file")
    else:
        try:
            check_apart(args.dataset, args.out)
        except ValueError as exc:
            raise _field_error(exc, "--out") from exc
    dataset = _open_dataset(args.dataset, kwargs.get("background_images"), features if lerobot else None,
                            _needed_keys(kwargs) if lerobot else None)
    generator, estimator = load_models(args, bool(kwargs.get("pose_offset")))
    if lerobot:
        from controltac_il.lerobot import staging_dir
    cache_dir = staging_dir(args.out) / "cache" if lerobot else args.out
    try:
        return ForceAugment(dataset, generator, cache_dir=cache_dir, estimator=estimator, build="manual",
                            progress=True, **kwargs)
    except StaleCacheError as exc:
        raise UsageError("--out", " ".join(str(exc).split())) from exc
    except ValueError as exc:
        raise _field_error(exc, "--dataset") from exc


def load_models(args, pose: bool):
    """(generator, estimator or None) of the flags; UsageError naming the flag."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.training import device_problem

    problem = device_problem(args.device)  # "--device ...: why", as the trainers say it
    if problem:
        raise UsageError(None, problem)

    estimator = None
    if args.estimator or args.generator is not None:  # a calibration bundle (--generator) brings its estimator
        from controltac_il.augment.reference import bundle_estimator, estimator_at

        flag = "--estimator" if args.estimator else "--generator"
        try:
            # a bundle as --estimator keeps its decision too: its estimator only where calibration said it may be used
            estimator = estimator_at(args.estimator) if args.estimator else bundle_estimator(args.generator)
        except (ValueError, OSError) as exc:
            raise UsageError(flag, f"expected a force estimator checkpoint folder: {' '.join(str(exc).split())}") from exc
    try:
        generator = ForceGenerator.from_pretrained(args.generator, device=args.device)
    except (ValueError, OSError) as exc:
        raise UsageError("--generator", f"expected a generator checkpoint folder (or default / fast / quality): "
                                        f"{' '.join(str(exc).split())}") from exc
    if pose:
        try:
            generator.load_pose_adapter(args.pose_adapter)
        except (ValueError, OSError) as exc:
            raise UsageError("--pose-adapter", " ".join(str(exc).split())) from exc
    return generator, estimator


def _pairs(args) -> dict[str, dict[str, str]]:
    """{setting: {key: value}} of the ``KEY=VALUE`` flags given (MAP_FLAGS); UsageError naming the flag for another
    form."""
    out = {}
    for name, (flag, form) in MAP_FLAGS.items():
        pairs = getattr(args, flag[2:].replace("-", "_"))
        try:
            out.update({} if pairs is None else {name: key_value_pairs(flag, pairs, form)})
        except ValueError as exc:
            raise UsageError(flag, str(exc).partition(": ")[2]) from None
    return out


def _lerobot_defaults(root: Path, kwargs: dict) -> dict:
    """Where --tactile-keys / --force-keys are not given, a LeRobot folder's tactile cameras and force labels as
    train_act.py takes them: cameras named gelsight / tactile / digit, labels observation.<camera>.force; a named
    tactile key that is none of its cameras is refused, naming them; the keys of --force-keys may be camera names
    too (ForceAugment itself takes them in --background-image). Returns the folder's features (info.json)."""
    from controltac_il.lerobot import read_info
    from controltac_il.lerobot.episodes import default_force_keys, tactile_cameras
    from controltac_il.streams import LEROBOT, tactile_key

    try:
        features = read_info(root)["features"]
    except (ValueError, OSError) as exc:
        raise _field_error(exc, "--dataset") from exc
    if not kwargs.get("tactile_keys"):
        kwargs["tactile_keys"] = tuple(tactile_cameras(features)) or None
    cameras = [k for k, f in features.items() if f.get("dtype") in ("video", "image")]
    unknown = [k for k in kwargs.get("tactile_keys") or () if k not in cameras and tactile_key(k, LEROBOT) not in cameras]
    if unknown:
        raise UsageError("--tactile-keys", f"{unknown[0]!r} is not a camera of {root}; its cameras are {cameras}")
    if kwargs.get("force_keys"):  # a camera's name stands for its key, as in --tactile-keys (and --background-image)
        keys = _feature_keys(kwargs["force_keys"], features)
        if len(set(keys)) < len(keys):
            raise UsageError("--force-keys", f"a camera is given twice, by its name and by its key: "
                                             f"{list(kwargs['force_keys'])}")
        kwargs["force_keys"] = dict(zip(keys, kwargs["force_keys"].values()))
    if kwargs.get("force_keys") is None and kwargs.get("tactile_keys"):
        kwargs["force_keys"] = default_force_keys(_feature_keys(kwargs["tactile_keys"], features), features) or None
    return features


def _feature_keys(keys, features: dict) -> list[str]:
    """``keys`` as a LeRobot folder's feature keys: a camera's name (gelsight_left) is its observation.images key
    where the folder has that key; any other key stays as given (for its refusal to name it)."""
    from controltac_il.streams import LEROBOT, tactile_key

    return [tactile_key(k, LEROBOT) if k not in features and tactile_key(k, LEROBOT) in features else k for k in keys]


def _needed_keys(kwargs: dict) -> list[str] | None:
    """The item keys ForceAugment reads when the tactile keys are named (their labels, backgrounds); None: all."""
    if not kwargs.get("tactile_keys"):
        return None
    maps = [kwargs.get(m) or {} for m in ("force_keys", "background_keys")]
    return [*kwargs["tactile_keys"], *(v for m in maps for v in m.values() if v)]


def _open_dataset(root: Path, background_images: dict | None, features: dict | None, keys: list[str] | None):
    """--dataset: a LeRobot v3.x folder of ``features`` (its info.json's; items of ``keys`` alone, None: all) or,
    with ``features`` None, a folder of ACT episodes (with ``background_images``, which then needs no estimate of
    its own)."""
    try:
        if features is not None:
            from controltac_il.lerobot import LeRobotFolder

            # an unknown key is the wrapper's to name (its flag)
            return LeRobotFolder(root, keys=None if keys is None else [k for k in _feature_keys(keys, features)
                                                                       if k in features],
                                 video_threads=0)  # the CLI never forks workers
        from controltac_il.datasets.act_dataset import EpisodeDataset

        return EpisodeDataset(root, chunk_size=1, cameras=[], background_images=background_images)
    except (ValueError, OSError) as exc:
        raise _field_error(exc, "--dataset") from exc


def _run(argv) -> None:
    args = parser().parse_args(argv)
    aug = _setup(args)
    from controltac_il.augment.provenance import StaleCacheError

    try:
        if args.lerobot:
            _report_lerobot(args.out, _write(aug, args.out, args.dataset, args.video_round_trip,
                                             args.export_workers))
        else:
            _report(aug, aug.build_cache())
    except StaleCacheError as exc:  # a chunk that does not provably belong to the cache
        raise UsageError("--out", " ".join(str(exc).split())) from exc


def main(argv=None) -> int:
    """Run the command; returns the exit status (0; 2 for a validation error, e.g. a flag, --out under a file, a
    full disk, a NaN force label in the data; 1 for a fault of the run, e.g. the generator's output not finite;
    130 when interrupted)."""
    return guard(PROG, lambda: _run(argv), interrupted="interrupted; every chunk written so far is complete: "
                                                       "re-run the same command to resume")
