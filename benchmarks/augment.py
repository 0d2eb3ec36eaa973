"""ForceAugment throughput: cache build frames/s and DataLoader items/s (bare, cached, online).

    python -m benchmarks.augment --out augment.json [--quick]

Episodes are recorded with the project's tactile sensor model (GelSight Mini, 240x320, two fingers
pressing a sphere with a ramp-hold-release normal force) and two RGB cameras, written as ACT HDF5
files in a temporary folder. Reads go through ``DataLoader(batch_size=8, shuffle, num_workers=2,
persistent_workers)``; items/s is the median over epochs of a fixed number of random items, the
readers taking turns epoch by epoch (the machine is shared: turns spread other load evenly).
Target: the cached wrapper reads within 10 % of the bare dataset.

The LeRobot-convention row reads the same episodes as a LeRobot dataset returns them (``LeRobotConvention``):
the two tactile streams as cameras ``observation.images.gelsight_<s>``, every image float32 (3, H, W) in
[0, 1], ``index``, ``timestamp``, ``task``, no backgrounds (ForceAugment estimates each episode's), and the
force labels under ``observation.gelsight_<s>.force``, named by ``force_keys=``. Without them the shipped
estimator reads these sensor-model renders with more than 1 N of shear, outside the generator's validated
range, so every frame would be kept real and online mode would generate nothing: the counts without labels
are reported beside the row.

The LeRobot writer row (``--rows lerobot_write``) writes the same episodes as a LeRobot v3.0 folder
(``benchmarks.lerobot_source``: gelsight_left an image feature, gelsight_right an AV1 video, per-episode stats
of every feature as ``lerobot-record`` writes them) and times ``python -m controltac_il.augment --dataset ROOT
--out OUT``'s whole write (cache build with the episodes' reading and, beside it, the export: PNGs, re-encoded
videos, stats, meta) against the time the generator alone spends on the same frames (its ``generate_at`` calls in
a cache build with nothing beside it; inside the write they share the cores with the export, so their time there,
``generator_seconds_in_write``, is reported but not compared with), in wall seconds and in this process's CPU
seconds (``time.process_time``, every thread: torch's intra-op threads, the codecs'), so that a machine shared
with other work still gives a comparison (CPU seconds are inflated too where torch's threads spin-wait for a
core). Target: the writer at >= 0.8x the generator's throughput. The same write is then timed again with
``--video-round-trip`` (every re-encoded video decoded back): its cost (``round_trip_cpu_seconds``) and its MSE
(uint8 units) of the regenerated frames, reported beside the generator's own error (README,
``benchmarks/results/generator.json``).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, RandomSampler

from benchmarks.common import base_parser, print_table, write_results
from controltac_il.augment import ForceAugment
from controltac_il.datasets import Episode, EpisodeDataset, write_episode
from controltac_il.tactile import SensorSpec, TactileSensor

SENSORS = ("left", "right")
WRITE_ROUNDS = 3  # the writer row's rounds (medians; the machine is shared)


def force_profile(T: int, peak: float, rng: np.random.Generator) -> np.ndarray:
    """Normal force (T,) N: free approach (no contact), ramp to ``peak``, hold with noise, release."""
    t0, t1, t2 = int(0.25 * T), int(0.45 * T), int(0.9 * T)
    fz = np.zeros(T)
    fz[t0:t1] = np.linspace(0.5, peak, t1 - t0)
    fz[t1:t2] = peak + rng.normal(0, 0.2, t2 - t1)
    return np.clip(fz, 0, None)


def record_episodes(root: Path, episodes: int, frames: int, seed: int = 0) -> None:
    """Write ``episodes`` ACT episodes with two tactile sensors (force labels and backgrounds) and two cameras."""
    sensor = TactileSensor(SensorSpec.gelsight_mini(), optics="polynomial", seed=seed)
    bg = sensor.background
    rng = np.random.default_rng(seed)
    for e in range(episodes):
        fz = force_profile(frames, rng.uniform(3.0, 7.0), rng)
        pose = (rng.uniform(-2, 2), rng.uniform(-2, 2), 0.0)
        tactile, force, rendered = {}, {}, {}
        for s in SENSORS:
            imgs = np.repeat(bg[None], frames, 0).copy()
            f = np.zeros((frames, 3), np.float32)
            for t in np.flatnonzero(fz > 0.2):
                q = round(float(fz[t]) * 4) / 4  # render once per 0.25 N step
                if q not in rendered:
                    rendered[q] = sensor.press("big_sphere", pose=pose, force=(0.0, 0.0, q)).image
                imgs[t] = rendered[q]
                f[t] = (0.0, 0.0, q)
            tactile[s], force[s] = imgs, f
        write_episode(root / f"episode_{e}.hdf5", Episode(
            qpos=rng.normal(size=(frames, 5)).astype(np.float32),
            action=rng.normal(size=(frames, 5)).astype(np.float32),
            images={c: rng.integers(0, 256, (frames, 240, 320, 3), dtype=np.uint8) for c in ("third_view", "wrist")},
            tactile=tactile, tactile_background={s: bg for s in SENSORS}, force=force, sim=True))


class LeRobotConvention(Dataset):
    """The frames of an EpisodeDataset as a LeRobot dataset returns them (no labels, no backgrounds), with
    LeRobot's ``hf_dataset`` index columns and ``fps``."""

    fps = 10

    def __init__(self, episodes: EpisodeDataset):
        self.episodes = episodes
        eps, frames = episodes.frame_table()
        self.hf_dataset = {"episode_index": eps.tolist(), "frame_index": frames.tolist()}

    def __len__(self) -> int:
        return len(self.episodes)

    def __getitem__(self, i: int) -> dict:
        src = self.episodes[i]
        item = {"episode_index": torch.tensor(src["episode_index"]), "frame_index": torch.tensor(src["frame_index"]),
                "index": torch.tensor(i), "timestamp": torch.tensor(src["frame_index"] / self.fps, dtype=torch.float32),
                "task_index": torch.tensor(0), "task": "grasp", "observation.state": src["observation.qpos"],
                "action": src["action"][0]}
        for k, v in src.items():
            if k.startswith("observation.images."):
                item[k] = v.float() / 255
            elif k.startswith("observation.tactile."):
                item["observation.images.gelsight_" + k.rsplit(".", 1)[1]] = v.float() / 255
            elif k.startswith("observation.force."):
                item[f"observation.gelsight_{k.rsplit('.', 1)[1]}.force"] = v
        return item


def lerobot_row(tmp: Path, gen, copies: int, steps, items: int, epochs: int, online_items: int) -> dict:
    """items/s of the LeRobot-convention dataset bare, cached and online, and its cache build."""
    import warnings

    bare = LeRobotConvention(EpisodeDataset(tmp / "demos", chunk_size=1, stats_path=tmp / "stats_lerobot.json"))
    keys = [f"observation.images.gelsight_{s}" for s in SENSORS]
    labels = {k: f"observation.gelsight_{s}.force" for k, s in zip(keys, SENSORS)}
    torch.set_num_threads(2)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
        t0 = time.perf_counter()
        cached = ForceAugment(bare, gen, copies=copies, cache_dir=tmp / "cache_lerobot", steps=steps, tactile_keys=keys,
                              force_keys=labels)
        build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        online = ForceAugment(bare, gen, copies=copies, mode="online", steps=steps, tactile_keys=keys,
                              force_keys=labels, progress=False)
        setup_s = time.perf_counter() - t0
        unlabelled = ForceAugment(bare, gen, copies=copies, mode="online", steps=steps, tactile_keys=keys,
                                  progress=False).summary()
    summary = cached.summary()
    torch.set_num_threads(1)
    rates = items_per_s({"bare": (bare, items), "cached": (cached, items)}, items, epochs)
    rates.update(items_per_s({"online": (online, online_items)}, online_items, 1))
    generated = summary["regenerated"] + summary["clamped"]
    return {"items_per_s": rates, "cached_vs_bare": rates["cached"] / rates["bare"],
            "cache_build": {"frames_generated": generated, "seconds": build_s, "frames_per_s": generated / build_s,
                            "torch_threads": 2, "steps": cached.steps},
            "online_setup_seconds": setup_s, "counts": summary, "counts_without_labels": unlabelled,
            "reference_force": "labels (force_keys=)", "background": "estimated per episode",
            "images": "float32 (3, H, W) in [0, 1]", "tactile_keys": keys}


class TimedGenerator:
    """The generator, with the wall seconds (``seconds``) and this process's CPU seconds (``cpu_seconds``, every
    thread: torch's intra-op threads run inside the call) spent in its ``generate_at`` calls summed."""

    def __init__(self, generator):
        self.generator, self.seconds, self.cpu_seconds = generator, 0.0, 0.0

    def __getattr__(self, name):
        return getattr(self.generator, name)

    def generate_at(self, *args, **kwargs):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return self.generator.generate_at(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0
            self.cpu_seconds += time.process_time() - c0


def _augment(source, gen, copies: int, steps, cache_dir: Path) -> ForceAugment:
    """ForceAugment over ``source``'s tactile streams as the CLI opens it (a folder of its own, tactile keys only)."""
    from benchmarks.lerobot_source import FORCES
    from controltac_il.datasets.lerobot_v3 import LeRobotFolder

    tactile_only = LeRobotFolder(source.root, keys=[*FORCES, *FORCES.values()], video_threads=0)
    return ForceAugment(tactile_only, gen, copies=copies, steps=steps, tactile_keys=list(FORCES), force_keys=FORCES,
                        cache_dir=cache_dir, build="manual", progress=True)


def generator_alone(source, cache_dir: Path, gen, copies: int, steps) -> dict:
    """Wall and CPU seconds of the generator's own calls when the same frames are generated with nothing beside it
    (a cache build alone: its reading is not timed)."""
    import warnings

    timed = TimedGenerator(gen)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
        _augment(source, timed, copies, steps, cache_dir).build_cache()
    return {"generator_seconds": timed.seconds, "generator_cpu_seconds": timed.cpu_seconds}


def timed_write(source, out: Path, gen, copies: int, steps, round_trip: bool) -> tuple[dict, dict, int]:
    """``python -m controltac_il.augment --dataset SOURCE --out OUT``'s write (cache build and export beside it),
    timed: (wall and CPU seconds of the whole write and of the generator's calls inside it, the write's record,
    sampler steps)."""
    import warnings

    from controltac_il.augment.to_lerobot import staging_dir, write_lerobot

    timed = TimedGenerator(gen)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
        t0, c0 = time.perf_counter(), time.process_time()
        aug = _augment(source, timed, copies, steps, staging_dir(out) / "cache")
        marker = write_lerobot(aug, source, out, round_trip=round_trip)["marker"]
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    times = {"write_seconds": wall, "write_cpu_seconds": cpu, "generator_seconds_in_write": timed.seconds,
             "generator_cpu_seconds_in_write": timed.cpu_seconds}
    return times, marker, aug.steps


def sequential_write(source, out: Path, gen, copies: int, steps) -> dict:
    """The same write with the export after the whole build (the writer before the export ran beside the build;
    the build still reads ahead), left unpublished in its staging folder: wall and CPU seconds."""
    import warnings

    from controltac_il.augment.lerobot_out import LeRobotExport
    from controltac_il.augment.to_lerobot import claim, finish, signature, staging_dir

    staging = staging_dir(out)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
        t0, c0 = time.perf_counter(), time.process_time()
        aug = _augment(source, gen, copies, steps, staging / "cache")
        sig = signature(aug, source)
        claim(staging, sig)
        aug.build_cache()
        export = LeRobotExport(aug, source, staging / "dataset", staging / "done")
        export.write()
        finish(export, sig)
        return {"write_seconds": time.perf_counter() - t0, "write_cpu_seconds": time.process_time() - c0}


def _median(runs: list[dict]) -> dict:
    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def lerobot_write_row(tmp: Path, gen, copies: int, steps, rounds: int) -> dict:
    """A LeRobot folder in, an augmented LeRobot folder out: ``rounds`` rounds of the generator alone, the write,
    and the write with its export after the build, on the same frames (medians, wall and CPU); then the write with
    the codec round trip measured (its cost and error)."""
    from benchmarks.lerobot_source import write_source
    from controltac_il.datasets.lerobot_v3 import LeRobotFolder

    source = LeRobotFolder(write_source(tmp / "demos", tmp / "lerobot_source"), video_threads=0)  # as the CLI
    alone, plain, after = [], [], []
    for r in range(rounds):
        alone.append(generator_alone(source, tmp / f"generator_alone_{r}", gen, copies, steps))
        times, marker, steps = timed_write(source, tmp / f"lerobot_augmented_{r}", gen, copies, steps, False)
        plain.append(times)
        after.append(sequential_write(source, tmp / f"lerobot_sequential_{r}", gen, copies, steps))
    checked, checked_marker, _ = timed_write(source, tmp / "lerobot_round_trip", gen, copies, steps, round_trip=True)
    gen_s = _median(alone)
    medians = {**_median(plain), "export_after_build": _median(after)}
    for times in (medians, medians["export_after_build"], checked):
        times.update({"writer_vs_generator": gen_s["generator_seconds"] / times["write_seconds"],
                      "writer_vs_generator_cpu": gen_s["generator_cpu_seconds"] / times["write_cpu_seconds"],
                      "writer_own_cpu_seconds": times["write_cpu_seconds"] - gen_s["generator_cpu_seconds"]})
    n = marker["regenerated_frames"]
    row = {"regenerated_frames": n, "rounds": rounds, **gen_s, **medians,
           "writer_frames_per_s": n / medians["write_seconds"], "generator_frames_per_s": n / gen_s["generator_seconds"],
           "target_0_8x": medians["writer_vs_generator"] >= 0.8,
           "per_round": [{"generator_seconds": a["generator_seconds"], "write_seconds": p["write_seconds"],
                          "export_after_build_seconds": q["write_seconds"]} for a, p, q in zip(alone, plain, after)],
           "generator_cores": gen_s["generator_cpu_seconds"] / gen_s["generator_seconds"],
           "episodes_written": marker["episodes"]["written"], "frames_written": marker["frames"],
           "video_round_trip_mse": checked_marker["video_round_trip_mse"],
           "video_round_trip_psnr_db": checked_marker["video_round_trip_psnr_db"], "with_round_trip": checked,
           "round_trip_cpu_seconds": checked["write_cpu_seconds"] - medians["write_cpu_seconds"],
           "steps": steps, "source": "gelsight_left image (PNG), gelsight_right AV1 video, two AV1 cameras; "
                                     "per-episode stats of every feature in meta/episodes, as lerobot-record writes"}
    print_table([{"write": name, **gen_s, **t} for name, t in (("export beside the build", medians), (
        "export after the build", medians["export_after_build"]), ("with the round trip", checked))],
                ["write", "write_seconds", "generator_seconds", "writer_vs_generator", "write_cpu_seconds",
                 "generator_cpu_seconds", "writer_vs_generator_cpu"],
                title=f"LeRobot folder in, augmented LeRobot folder out (medians of {rounds} rounds; round trip: one)")
    return row


def items_per_s(readers: dict, items: int, rounds: int, seed: int = 0) -> dict:
    """Median items/s of each reader over ``rounds`` epochs of ``items`` random items.

    One persistent 2-worker DataLoader per reader; the readers take turns epoch by epoch (after one
    warm-up epoch each), so load from other processes on the machine hits them alike.
    """
    loaders = {}
    for name, (dataset, n) in readers.items():
        sampler = RandomSampler(dataset, replacement=False, num_samples=min(n, len(dataset)),
                                generator=torch.Generator().manual_seed(seed))
        loaders[name] = DataLoader(dataset, batch_size=8, sampler=sampler, num_workers=2, persistent_workers=True)
    rates = {name: [] for name in readers}
    for r in range(rounds + 1):
        for name, loader in loaders.items():
            t0 = time.perf_counter()
            n = sum(len(b["frame_index"]) for b in loader)
            if r:
                rates[name].append(n / (time.perf_counter() - t0))
    return {name: float(np.median(v)) for name, v in rates.items()}


def load_generator(path: str | None):
    """The given or shipped checkpoint; else the default architecture, randomly initialised (same speed)."""
    from controltac_il.generator import ForceGenerator, GeneratorConfig

    try:
        return ForceGenerator.from_pretrained(path), path or "shipped default"
    except FileNotFoundError:
        if path is not None:
            raise
        from controltac_il.generator.autoencoder import TactileAutoencoder
        from controltac_il.generator.dit import ForceDiT

        torch.manual_seed(0)
        cfg = GeneratorConfig()
        gen = ForceGenerator(cfg, TactileAutoencoder(cfg.autoencoder), ForceDiT(cfg.dit), checkpoint_hash="random-init")
        return gen, "default architecture, randomly initialised (no shipped checkpoint found)"


def hdf5_row(tmp: Path, gen, args, copies: int, steps, items: int, epochs: int, online_items: int) -> dict:
    """Our HDF5 episodes: cache build, items/s bare / cached / online, the clamp and skip counts (printed)."""
    bare = EpisodeDataset(tmp / "demos", chunk_size=20, stats_path=tmp / "stats.json")
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    cached = ForceAugment(bare, gen, copies=copies, cache_dir=tmp / "cache", steps=steps, progress=True)
    build_s = time.perf_counter() - t0
    summary = cached.summary()
    generated = summary["regenerated"] + summary["clamped"]
    torch.set_num_threads(1)  # the readers: two DataLoader workers
    online = ForceAugment(bare, gen, copies=copies, mode="online", steps=steps)
    rates = items_per_s({"bare": (bare, items), "cached": (cached, items)}, items, epochs)
    rates.update(items_per_s({"online": (online, online_items)}, online_items, 1))
    skipped = ForceAugment(bare, gen, copies=copies, out_of_range="skip", mode="online", steps=steps).summary()["skipped"]
    build = {"frames_generated": generated, "seconds": build_s, "frames_per_s": generated / build_s,
             "torch_threads": args.threads, "steps": cached.steps}
    print_table([build], list(build), title="cache build (incl. reading the episodes)")
    print_table([{**summary, "skipped_with_skip": skipped}],
                ["tactile_frames", "regenerated", "clamped", "skipped", "no_contact", "fraction_regenerated",
                 "skipped_with_skip"], title="augmented frames (clamp mode; skip mode counted from the same draws)")
    return {"cache_build": build, "items_per_s": rates, "cached_vs_bare": rates["cached"] / rates["bare"],
            "target_cached_within_10pct": rates["cached"] >= 0.9 * rates["bare"],
            "counts_clamp_mode": summary, "skipped_in_skip_mode": skipped}


def main(argv=None) -> dict:
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--generator", default=None, help="generator checkpoint folder (default: shipped)")
    p.add_argument("--threads", type=int, default=2, help="torch threads for the cache build (default 2)")
    p.add_argument("--steps", type=int, default=None,
                   help="sampler steps (default: the generator's; 2 with --quick)")
    p.add_argument("--rows", nargs="+", choices=("all", "hdf5", "lerobot", "lerobot_write"), default=["all"],
                   help="which rows: our HDF5 episodes, the LeRobot-convention view, the LeRobot folder writer "
                        "(default all)")
    args = p.parse_args(argv)
    episodes, frames, copies, items, epochs, online_items = (
        (3, 20, 2, 96, 2, 16) if args.quick else (6, 40, 4, 960, 9, 48))
    steps = args.steps if args.steps is not None else (2 if args.quick else None)
    torch.set_num_threads(args.threads)
    gen, gen_name = load_generator(args.generator)
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench-augment-") as tmp:
        tmp = Path(tmp)
        record_episodes(tmp / "demos", episodes, frames)
        sizes = (copies, steps, items, epochs, online_items)
        rows = {"hdf5", "lerobot", "lerobot_write"} if "all" in args.rows else set(args.rows)
        if "hdf5" in rows:
            results.update(hdf5_row(tmp, gen, args, *sizes))
        if "lerobot" in rows:
            results["lerobot"] = lerobot_row(tmp, gen, *sizes)
        if "lerobot_write" in rows:
            torch.set_num_threads(args.threads)
            results["lerobot_write"] = lerobot_write_row(tmp, gen, copies, steps, 1 if args.quick else WRITE_ROUNDS)
    table = [{"dataset": name, "reader": k, "items/s": v, "vs bare": v / rates["bare"]}
             for name, rates in (("hdf5", results.get("items_per_s")), ("lerobot", results.get("lerobot", {}).get(
                 "items_per_s"))) if rates for k, v in rates.items()]
    print_table(table, ["dataset", "reader", "items/s", "vs bare"], title="DataLoader(batch 8, 2 workers) items/s (median)")
    return write_results(args.out, {
        "benchmark": "augment",
        "quick": args.quick,
        "rows": sorted(rows),
        "generator": gen_name,
        "generator_hash": str(gen.checkpoint_hash),
        "data": {"episodes": episodes, "frames_per_episode": frames, "tactile": "2 x 240x320",
                 "cameras": "2 x 240x320", "copies": copies},
        **results,
    })


if __name__ == "__main__":
    main()
