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

The LeRobot writer row (``--rows lerobot_write``): ``benchmarks.lerobot_write``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, RandomSampler

from benchmarks.common import base_parser, load_generator, print_table, write_results
from controltac_il.augment import ForceAugment
from controltac_il.datasets import Episode, EpisodeDataset, write_episode
from controltac_il.streams import (HDF5_FORCE, HDF5_IMAGES, HDF5_STATE, HDF5_TACTILE, LEROBOT, LEROBOT_STATE, force_key,
                                   sensor_of, tactile_key)
from controltac_il.tactile import SensorSpec, TactileSensor

SENSORS = ("left", "right")
WRITE_ROUNDS = 5  # the writer row's rounds (medians; the machine is shared and its speed drifts by 20 %)

PROG = "python -m benchmarks.augment"


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
                "task_index": torch.tensor(0), "task": "grasp", LEROBOT_STATE: src[HDF5_STATE],
                "action": src["action"][0]}
        for k, v in src.items():
            if k.startswith(HDF5_IMAGES):
                item[k] = v.float() / 255
            elif k.startswith(HDF5_TACTILE):
                item[tactile_key("gelsight_" + sensor_of(k), LEROBOT)] = v.float() / 255
            elif k.startswith(HDF5_FORCE):
                item[force_key("gelsight_" + sensor_of(k), LEROBOT)] = v
        return item


def lerobot_row(tmp: Path, gen, copies: int, steps, items: int, epochs: int, online_items: int) -> dict:
    """items/s of the LeRobot-convention dataset bare, cached and online, and its cache build."""
    import warnings

    bare = LeRobotConvention(EpisodeDataset(tmp / "demos", chunk_size=1, stats_path=tmp / "stats_lerobot.json"))
    keys = [tactile_key(f"gelsight_{s}", LEROBOT) for s in SENSORS]
    labels = {k: force_key(f"gelsight_{s}", LEROBOT) for k, s in zip(keys, SENSORS)}
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
    p = base_parser(PROG, __doc__.splitlines()[0])
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
            from benchmarks.lerobot_write import lerobot_write_row

            results["lerobot_write"] = lerobot_write_row(tmp, tmp / "demos", args.generator, args.threads, copies,
                                                         steps, 1 if args.quick else WRITE_ROUNDS)
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
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
