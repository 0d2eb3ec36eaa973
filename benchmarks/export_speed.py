"""LeRobot export speed: the writer alone (its ForceAugment cache built), in 1 to N worker processes.

    python -m benchmarks.export_speed --out export_speed.json [--workers 1 2 4 ...] [--episodes N] [--quick]

The source (``benchmarks.lerobot_source`` over ``benchmarks.augment.record_episodes``): GelSight episodes at
240x320, ``gelsight_right`` an AV1 video feature, the tactile stream augmented here (each copy's video re-encoded),
``gelsight_left`` a PNG image feature and two AV1 cameras, copied. The cache is built once (the shipped default
generator on CPU, few sampler steps); then, for each worker count, the export alone (``LeRobotExport.write``:
source decode, re-encode, stats, data files and meta rows; worker start-up included) into a fresh folder, the
worker counts taking turns round by round, medians over rounds. Reported: output frames/s (frames of the output
episodes whose tactile video was re-encoded / wall s), regenerated frames/s, the speedup whole source episodes per
worker allow, and whether every worker count wrote the same bytes (a digest of the folder)."""

from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks.common import base_parser, load_generator, print_table, write_results
from benchmarks.lerobot_source import FORCES, VIDEO, write_source
from controltac_il.augment import ForceAugment
from controltac_il.lerobot import LeRobotExport, LeRobotFolder

SIZES = {False: {"frames": 100, "copies": 1, "steps": 2, "rounds": 3},  # episodes: --episodes
         True: {"frames": 20, "copies": 1, "steps": 1, "rounds": 1}}

PROG = "python -m benchmarks.export_speed"


def build_cache(root: Path, cache_dir: Path, copies: int, steps: int) -> tuple[ForceAugment, dict]:
    """ForceAugment over the tactile video stream of the source ``root``, its cache built: (it, the build's wall s
    and generated frames)."""
    warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
    gen, name = load_generator(None)
    tactile = LeRobotFolder(root, keys=[VIDEO, FORCES[VIDEO]], video_threads=0)
    aug = ForceAugment(tactile, gen, copies=copies, steps=steps, tactile_keys=[VIDEO],
                       force_keys={VIDEO: FORCES[VIDEO]}, cache_dir=cache_dir, build="manual", progress=False)
    t0 = time.perf_counter()
    built = aug.build_cache(progress=False)
    return aug, {"generator": name, "seconds": time.perf_counter() - t0, "generated_frames": built["generated"],
                 "steps": aug.steps}


def digest(folder: Path) -> str:
    """sha256 of every file under ``folder``: relative path and bytes, in path order (16 hex digits)."""
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(str(path.relative_to(folder)).encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


def timed_export(aug: ForceAugment, root: Path, out: Path, workers: int) -> dict:
    """One export of the whole source into the fresh folder ``out`` in ``workers`` processes: wall s, output
    episodes and frames, the frames of the output episodes whose tactile video was re-encoded, regenerated frames,
    the digest of what was written."""
    source = LeRobotFolder(root, video_threads=0)  # as the augment CLI opens it
    t0 = time.perf_counter()
    export = LeRobotExport(aug, source, out / "dataset", out / "done", workers=workers)
    counts = export.write(progress=False)
    wall = time.perf_counter() - t0
    rows, chunks = export.rows(), export.chunks_size
    encoded = [r for r in rows if r[f"videos/{VIDEO}/chunk_index"] * chunks + r[f"videos/{VIDEO}/file_index"]
               >= export.first_video[VIDEO]]
    result = {"seconds": wall, "source_episodes": len(export.sources), "episodes": counts["episodes"],
              "frames": sum(r["length"] for r in rows),
              "reencoded_frames": sum(r["length"] for r in encoded), "regenerated_frames": counts["regenerated"],
              "digest": digest(out)}
    shutil.rmtree(out)
    return result


def measure(aug: ForceAugment, root: Path, tmp: Path, workers: list[int], rounds: int) -> list[dict]:
    """Every worker count's exports, the counts taking turns (order reversed every other round): one row per worker
    count, median wall s over rounds and the rates of it; ``speedup_bound``: what whole source episodes per worker
    allow (E / ceil(E / workers), E source episodes)."""
    runs = {w: [] for w in workers}
    for r in range(rounds):
        for w in workers[:: 1 if r % 2 == 0 else -1]:
            runs[w].append(timed_export(aug, root, tmp / f"export_w{w}_r{r}", w))
    rows = []
    for w, results in runs.items():
        seconds = float(np.median([x["seconds"] for x in results]))
        first = results[0]
        rows.append({"workers": w, "seconds": seconds, "seconds_per_round": [x["seconds"] for x in results],
                     "output_frames_per_s": first["reencoded_frames"] / seconds,
                     "regenerated_frames_per_s": first["regenerated_frames"] / seconds,
                     **{k: first[k] for k in ("source_episodes", "episodes", "frames", "reencoded_frames",
                                              "regenerated_frames")},
                     "digests": sorted({x["digest"] for x in results})})
    base = next((row["seconds"] for row in rows if row["workers"] == 1), None)
    for row in rows:
        row["speedup_vs_1_worker"] = None if base is None else base / row["seconds"]
        row["speedup_bound"] = row["source_episodes"] / math.ceil(row["source_episodes"] / row["workers"])
    return rows


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4],
                   help="worker process counts to time (default: 1 2 4)")
    p.add_argument("--episodes", type=int, default=None, help="source episodes (default 32; 4 with --quick)")
    args = p.parse_args(argv)
    if min(args.workers) < 1:
        raise ValueError(f"--workers: expected worker counts >= 1, got {args.workers}")
    from benchmarks.augment import record_episodes  # here: the spawned export workers re-import this module

    size = SIZES[args.quick]
    episodes = args.episodes if args.episodes is not None else (4 if args.quick else 32)
    with tempfile.TemporaryDirectory(prefix="bench-export-") as tmp:
        tmp = Path(tmp)
        record_episodes(tmp / "demos", episodes, size["frames"])
        root = write_source(tmp / "demos", tmp / "source")
        aug, build = build_cache(root, tmp / "cache", size["copies"], size["steps"])
        rows = measure(aug, root, tmp, list(dict.fromkeys(args.workers)), size["rounds"])
    same = len({d for row in rows for d in row["digests"]}) == 1
    print_table(rows, ["workers", "seconds", "output_frames_per_s", "regenerated_frames_per_s", "speedup_vs_1_worker",
                       "speedup_bound"],
                title=f"LeRobot export alone, cache built (median of {size['rounds']} round(s); {episodes} episodes x "
                      f"{size['frames']} frames, {size['copies']} copy; same bytes for every worker count: {same})")
    return write_results(args.out, {
        "benchmark": "export_speed", "quick": args.quick,
        "data": {"episodes": episodes, "frames_per_episode": size["frames"], "copies": size["copies"],
                 "tactile": f"{VIDEO}: AV1 video 240x320, re-encoded in every copy", "rounds": size["rounds"]},
        "cache_build": build, "rows": rows, "same_bytes_for_every_worker_count": same})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
