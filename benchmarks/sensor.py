"""Sensor-model benchmark: frames/s, depth-solver iterations, and realism against real GelSight Mini frames.

    python -m benchmarks.sensor --out sensor.json [--quick] [--real-dir ../shared/data/real_gelsight_mini]

Realism: residual statistics of our frames beside those of real GelSight Mini contacts (when the real
frames are available; they are GPL-licensed, so they are read from ``--real-dir`` and never shipped),
plus a PNG with real frames on top and ours below.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import REAL_GELSIGHT, base_parser, median_time, print_table, write_results
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, SensorSpec, TactileSensor, to_residual
from controltac_il.tactile.residual import OFFSET, residual_magnitude
from controltac_il.tactile.sheet import save_png

REAL_CONTACTS = ("bead.png", "key.png", "seed.png", "ball_image.png")

PROG = "python -m benchmarks.sensor"


def residual_stats(residual: np.ndarray) -> dict:
    """Statistics of one residual (uint8 (H, W, 3)): magnitude percentiles, contact fraction, channel spread."""
    mag = residual_magnitude(residual)
    contact = mag > 15
    d = residual.astype(np.float32) - OFFSET
    inside = d[contact] if contact.any() else d.reshape(-1, 3)
    return {
        "max_abs": float(mag.max()),
        "p99_abs": float(np.percentile(mag, 99)),
        "contact_fraction": float(contact.mean()),
        "contact_mean_rgb": inside.mean(0).round(2).tolist(),
        "contact_std_rgb": inside.std(0).round(2).tolist(),
        "background_noise_std": float(d[~contact].std()) if (~contact).any() else None,
    }


def summarize(stats: list[dict]) -> dict:
    keys = ("max_abs", "p99_abs", "contact_fraction", "background_noise_std")
    out = {k: float(np.mean([s[k] for s in stats if s[k] is not None])) for k in keys}
    out["contact_std_rgb"] = np.mean([s["contact_std_rgb"] for s in stats], axis=0).round(2).tolist()
    return out


def simulated_contacts(sensor: TactileSensor, n: int, seed: int = 0):
    """Firm contacts (3–10 N) of all objects at random poses: (name, image) pairs."""
    rng = np.random.default_rng(seed)
    objects = TRAIN_OBJECTS + HELDOUT_OBJECTS
    out = []
    for i in range(n):
        obj = objects[i % len(objects)]
        pose = (rng.uniform(-4, 4), rng.uniform(-3, 3), rng.uniform(0, np.pi))
        force = (rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(3, 10))
        out.append((obj, sensor.press(obj, pose, force, noise_seed=i).image))
    return out


def run(quick: bool, real_dir: Path, picture: Path | None) -> dict:
    rows, speed = [], {}
    n_frames = 8 if quick else 40
    for optics in ("three_light", "polynomial"):
        for h, w in ((240, 320), (120, 160)):
            sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(h, w), optics=optics)
            rng = np.random.default_rng(0)
            cases = [(TRAIN_OBJECTS[i % 6], (rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(0, 3)),
                      (0.0, 0.0, rng.uniform(*VALIDATED_RANGE.fz))) for i in range(n_frames)]
            iters = []

            def render_all():
                iters.clear()
                for obj, pose, force in cases:
                    iters.append(sensor.press(obj, pose, force).iterations)

            t = median_time(render_all, repeats=3 if quick else 5)
            row = {"optics": optics, "resolution": f"{h}x{w}", "frames_per_s": n_frames / t,
                   "ms_per_frame": 1e3 * t / n_frames, "solver_iters_median": float(np.median(iters)),
                   "solver_iters_max": int(max(iters))}
            rows.append(row)
    print_table(rows, ["optics", "resolution", "frames_per_s", "ms_per_frame", "solver_iters_median", "solver_iters_max"],
                title="sensor model speed (median of repeats; all frames include the depth solve)")
    speed = rows

    realism = {}
    sensor = TactileSensor(optics="three_light")
    sims = simulated_contacts(sensor, 8 if quick else 24)
    ours = [residual_stats(to_residual(img, sensor.background)) for _, img in sims]
    realism["ours_three_light"] = summarize(ours)
    poly = TactileSensor(optics="polynomial")
    realism["ours_polynomial"] = summarize(
        [residual_stats(to_residual(img, poly.background)) for _, img in simulated_contacts(poly, 8 if quick else 24)])
    real_frames = []
    if (real_dir / "background.png").is_file():
        read = lambda n: cv2.cvtColor(cv2.imread(str(real_dir / n)), cv2.COLOR_BGR2RGB)  # noqa: E731
        bg = read("background.png")
        real_frames = [read(n) for n in REAL_CONTACTS if (real_dir / n).is_file()]
        realism["real_gelsight_mini"] = summarize([residual_stats(to_residual(f, bg)) for f in real_frames])
    else:
        realism["real_gelsight_mini"] = None
        print(f"(no real frames at {real_dir}: realism compares nothing)")
    table = [{"source": k, **{m: v[m] for m in ("max_abs", "p99_abs", "contact_fraction", "background_noise_std")},
              "contact_std_rgb": v["contact_std_rgb"]} for k, v in realism.items() if v]
    print_table(table, ["source", "max_abs", "p99_abs", "contact_fraction", "background_noise_std", "contact_std_rgb"],
                title="residual statistics (grey levels; contact = |residual| > 15)")
    if picture is not None and real_frames:
        top = np.hstack(real_frames[:4])
        bottom = np.hstack([img for _, img in sims[:4]])
        save_png(picture, np.vstack([top, bottom]))
        print(f"wrote {picture} (top: real GelSight Mini, bottom: sensor model)")
    return {"speed": speed, "realism": realism}


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--real-dir", type=Path, default=REAL_GELSIGHT, help="folder with real GelSight Mini frames")
    p.add_argument("--picture", type=Path, default=None, help="PNG of real frames above ours (default: beside --out)")
    args = p.parse_args(argv)
    if args.real_dir != REAL_GELSIGHT and not args.real_dir.is_dir():  # the default may be absent: no comparison
        p.error(f"--real-dir {args.real_dir} is not a folder")
    picture = args.picture or (args.out.with_name(args.out.stem + "_realism.png") if args.out else None)
    t0 = time.perf_counter()
    results = run(args.quick, args.real_dir, picture)
    results["wall_s"] = time.perf_counter() - t0
    return write_results(args.out, {"benchmark": "sensor", "quick": args.quick, **results})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
