"""Force estimator across sensors: MAE per axis on seen / unseen objects x seen / unseen sensors, and its
readings of real GelSight Mini presses.

    python -m benchmarks.estimator --out estimator.json [--checkpoint NAME=PATH ...] [--quick]

Test sets are rendered here (seeds 900-903, never a training seed) at 120x160: the six training objects
("seen") or the six held-out ones ("unseen"), each contact pose with one instance of a sensor family: "seen
sensors" = the training family's first 24 instances (``controltac_il.tactile.instances``), "unseen sensor" =
the held-out family (polynomial optics over the DIGIT background, brighter lighting). The one-sensor column is
the sensor model's default GelSight Mini, which the first estimator was trained on. Target: unseen-sensor MAE
within 2x the seen-sensor MAE.

Real presses (``../shared/data/real_gelsight_mini``, GPL-3.0, measured against only): no label exists; a light
press of a bead, a key or a seed is a few N with well under 1 N of shear. "plausible" = 0 < Fz <= 15 N and
|Fx|, |Fy| <= 1 N.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import REAL_GELSIGHT, REAL_PRESSES, base_parser, print_table, real_gelsight, write_results
from controltac_il.estimators import ForceEstimator
from controltac_il.estimators.data import load_arrays
from controltac_il.tactile.dataset import load_dataset, write_dataset
from controltac_il.tactile.indenters import HELDOUT_OBJECTS, TRAIN_OBJECTS
from controltac_il.tactile.residual import to_residual
from controltac_il.tactile.spec import SensorSpec

CELLS = {"seen_objects/one_sensor": (TRAIN_OBJECTS, None, 900), "seen_objects/seen_sensors": (TRAIN_OBJECTS, "train", 901),
         "seen_objects/unseen_sensor": (TRAIN_OBJECTS, "unseen", 902),
         "unseen_objects/seen_sensors": (HELDOUT_OBJECTS, "train", 903),
         "unseen_objects/unseen_sensor": (HELDOUT_OBJECTS, "unseen", 904)}

PROG = "python -m benchmarks.estimator"


def render(tmp: Path, poses: int, forces: int) -> dict:
    """{cell: (residuals uint8 (N, 120, 160, 3), forces (N, 3))}."""
    out = {}
    for cell, (objects, family, seed) in CELLS.items():
        path = write_dataset(tmp / cell.replace("/", "-"), objects, poses_per_object=poses, forces_per_pose=forces,
                             seed=seed, spec=SensorSpec.gelsight_mini().scaled(120, 160), sensors=family,
                             instances=24, progress=False)
        out[cell] = load_arrays(load_dataset(path))
    return out


def real_presses(frames: Path) -> np.ndarray | None:
    """Residuals (3, 240, 320, 3) of the real presses, None where the frames are not there."""
    try:
        bg, presses = real_gelsight(frames)
    except FileNotFoundError:
        return None
    return np.stack([to_residual(f, bg) for f in presses.values()])


def evaluate(estimator, cells: dict, real: np.ndarray | None) -> dict:
    row = {}
    for cell, (residuals, forces) in cells.items():
        err = np.abs(estimator.predict(residuals) - forces)
        row[cell] = {"mae": err.mean(0).round(4).tolist(), "mae_fz": float(err[:, 2].mean()), "n": len(forces)}
    row["unseen_vs_seen_sensor"] = row["seen_objects/unseen_sensor"]["mae_fz"] / row["seen_objects/seen_sensors"]["mae_fz"]
    if real is not None:
        est = estimator.predict(real).astype(float)
        row["real_presses"] = {n: {"force_n": f.round(2).tolist(),
                                   "plausible": bool(0 < f[2] <= 15 and abs(f[0]) <= 1 and abs(f[1]) <= 1)}
                               for n, f in zip(REAL_PRESSES, est)}
    return row


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--checkpoint", nargs="+", default=["shipped=default"], metavar="NAME=PATH",
                   help="estimators to measure (default: the shipped one, 'shipped=default')")
    p.add_argument("--frames", type=Path, default=REAL_GELSIGHT, help=f"real GelSight Mini frames (default {REAL_GELSIGHT})")
    args = p.parse_args(argv)
    torch.set_num_threads(2)
    poses, forces = (2, 2) if args.quick else (8, 4)
    named = dict(c.split("=", 1) for c in args.checkpoint)
    with tempfile.TemporaryDirectory(prefix="bench-estimator-") as tmp:
        cells = render(Path(tmp), poses, forces)
    real = real_presses(args.frames)
    rows = {}
    for name, path in named.items():
        est = ForceEstimator.from_pretrained(None if path == "default" else path)
        rows[name] = {"checkpoint": path, "hash": str(est.checkpoint_hash), **evaluate(est, cells, real)}
    table = [{"estimator": n, **{c: f"{r[c]['mae_fz']:.2f}" for c in CELLS},
              "unseen/seen sensor": f"{r['unseen_vs_seen_sensor']:.2f}",
              "real plausible": sum(v["plausible"] for v in r.get("real_presses", {}).values())} for n, r in rows.items()]
    print_table(table, list(table[0]), title="Fz MAE (N) per cell")
    return write_results(args.out, {"benchmark": "estimator", "quick": args.quick, "poses_per_object": poses,
                                    "forces_per_pose": forces, "resolution": [120, 160], "estimators": rows,
                                    "target_unseen_vs_seen_sensor": 2.0})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
