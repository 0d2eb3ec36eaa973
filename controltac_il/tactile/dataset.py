"""Tactile datasets in the FeelAnyForce layout: images plus a CSV manifest, one row per image.

Layout of a dataset folder::

    manifest.csv     image, object, pose_id, x_mm, y_mm, theta_rad, fx, fy, fz
    background.png   the sensor's no-contact frame (RGB PNG)
    meta.json        generator settings (spec, optics, seed, counts, force convention)
    images/<object>/<pose_id>_<k>.png

Forces are stored in the project's convention (N, sensor frame, Fz > 0 pressing). Real FeelAnyForce
recordings store Fz < 0 when pressing; ``load_dataset`` detects that (or is told) and flips the sign.

Command line (the generator's and estimator's training data)::

    python -m controltac_il.tactile.dataset --out data/train600 --poses-per-object 600 --seed 0 --size 120 160
"""

from __future__ import annotations

import argparse
import csv
import inspect
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from tqdm.auto import tqdm

from controltac_il.io import atomic_dir
from controltac_il.tactile.indenters import INDENTERS, TRAIN_OBJECTS, get_indenter
from controltac_il.tactile.residual import to_residual
from controltac_il.tactile.sensor import TactileSensor
from controltac_il.tactile.spec import SensorSpec

MANIFEST_FIELDS = ("image", "object", "pose_id", "x_mm", "y_mm", "theta_rad", "fx", "fy", "fz")
REQUIRED_FIELDS = ("image", "object", "pose_id", "fx", "fy", "fz")


@dataclass(frozen=True)
class TactileRecord:
    """One manifest row: the image path (relative to the dataset), the contact pose and force (N)."""

    image: str
    object: str
    pose_id: int
    pose: tuple[float, float, float]
    force: tuple[float, float, float]


def sample_contacts(objects: Sequence[str], poses_per_object: int, forces_per_pose: int, seed: int,
                    spec: SensorSpec, fz_range=(0.5, 11.0), shear_max: float = 1.0):
    """Deterministic contact list: each (object, pose) draws from its own stream keyed by (seed, object, pose).

    Yields (object, pose_id, pose (x, y, θ), [(fx, fy, fz), ...], noise seeds).
    """
    half_h, half_w = (s / 2 for s in spec.pad_size_mm)
    for oi, name in enumerate(objects):
        get_indenter(name)
        for pid in range(poses_per_object):
            rng = np.random.default_rng([seed, oi, pid])
            pose = (rng.uniform(-0.6, 0.6) * half_w, rng.uniform(-0.6, 0.6) * half_h, rng.uniform(0, np.pi))
            fz = rng.uniform(*fz_range, size=forces_per_pose)
            fxy = rng.uniform(-shear_max, shear_max, size=(forces_per_pose, 2))
            forces = [(float(a), float(b), float(c)) for (a, b), c in zip(fxy, fz)]
            noise = rng.integers(0, 2**31, size=forces_per_pose)
            yield name, pid, pose, forces, [int(n) for n in noise]


def write_dataset(out_dir, objects: Sequence[str] = TRAIN_OBJECTS, poses_per_object: int = 50,
                  forces_per_pose: int = 8, seed: int = 0, spec: SensorSpec | None = None,
                  optics: str = "three_light", fz_range=(0.5, 11.0), shear_max: float = 1.0,
                  progress: bool = True) -> Path:
    """Render a sensor-model dataset into ``out_dir`` (built in a temporary folder, renamed when complete).

    Every image is a pure function of (seed, object, pose_id, k): the same arguments give the same files.
    """
    if poses_per_object < 1 or forces_per_pose < 1:
        raise ValueError("poses_per_object and forces_per_pose must be >= 1")
    if not (0 <= fz_range[0] < fz_range[1]):
        raise ValueError(f"fz_range must be (low, high) with 0 <= low < high N, got {fz_range!r}")
    spec = spec or SensorSpec.gelsight_mini()
    sensor = TactileSensor(spec, optics=optics)
    out_dir = Path(out_dir)
    total = len(objects) * poses_per_object * forces_per_pose
    with atomic_dir(out_dir) as tmp:
        cv2.imwrite(str(tmp / "background.png"), cv2.cvtColor(sensor.background, cv2.COLOR_RGB2BGR))
        rows = []
        with tqdm(total=total, desc=f"rendering {out_dir.name}", unit="img", disable=not progress) as bar:
            for name, pid, pose, forces, noise in sample_contacts(objects, poses_per_object, forces_per_pose, seed, spec, fz_range, shear_max):
                (tmp / "images" / name).mkdir(parents=True, exist_ok=True)
                for k, (force, ns) in enumerate(zip(forces, noise)):
                    c = sensor.press(name, pose, force, noise_seed=ns)
                    rel = f"images/{name}/{pid:04d}_{k:02d}.png"
                    cv2.imwrite(str(tmp / rel), cv2.cvtColor(c.image, cv2.COLOR_RGB2BGR))
                    rows.append([rel, name, pid, *(f"{v:.6f}" for v in pose), *(f"{v:.6f}" for v in c.force)])
                    bar.update()
        with open(tmp / "manifest.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(MANIFEST_FIELDS)
            w.writerows(rows)
        meta = {"spec": spec.to_dict(), "optics": optics, "seed": seed, "objects": list(objects),
                "poses_per_object": poses_per_object, "forces_per_pose": forces_per_pose,
                "fz_range": list(fz_range), "shear_max": shear_max, "fz_pressing": "positive", "count": total}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
    return out_dir


class TactileDataset:
    """A loaded dataset folder: records, images and residuals (uint8 RGB (H, W, 3))."""

    def __init__(self, root: Path, records: list[TactileRecord], background: np.ndarray | None, meta: dict):
        self.root, self.records, self.background, self.meta = root, records, background, meta

    def __len__(self) -> int:
        return len(self.records)

    def image(self, i: int) -> np.ndarray:
        path = self.root / self.records[i].image
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"manifest row {i}: cannot read image {path}")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def residual(self, i: int) -> np.ndarray:
        if self.background is None:
            raise ValueError(f"{self.root} has no background.png: residuals need the no-contact frame")
        return to_residual(self.image(i), self.background)

    def forces(self) -> np.ndarray:
        """All forces, float32 (N, 3) in N."""
        return np.asarray([r.force for r in self.records], dtype=np.float32)

    def pose_groups(self) -> dict[tuple[str, int], list[int]]:
        """Indices of the images of each contact pose (object, pose_id): pairs are formed within a group."""
        groups: dict[tuple[str, int], list[int]] = {}
        for i, r in enumerate(self.records):
            groups.setdefault((r.object, r.pose_id), []).append(i)
        return groups


def _field(row: dict, name: str, line: int, cast):
    for key in (name, name.upper(), name.capitalize(), "F" + name[1:] if name.startswith("f") else name):
        if key in row and row[key] not in (None, ""):
            try:
                value = cast(row[key])
            except ValueError:
                raise ValueError(f"manifest line {line}: field {name!r} must be {cast.__name__}, got {row[key]!r}") from None
            if isinstance(value, float) and not np.isfinite(value):
                raise ValueError(f"manifest line {line}: field {name!r} must be finite, got {row[key]!r}")
            return value
    raise ValueError(f"manifest line {line}: missing field {name!r}")


def load_dataset(root, fz_pressing: str = "auto") -> TactileDataset:
    """Load a dataset folder written by ``write_dataset`` or a real FeelAnyForce-style recording.

    ``fz_pressing``: "positive" (project convention), "negative" (FeelAnyForce: flip Fz and the
    frame), or "auto" (meta.json's value if present, else negative when most Fz are < 0).
    """
    root = Path(root)
    manifest = root / "manifest.csv"
    if not manifest.is_file():
        raise ValueError(f"{root} is not a tactile dataset: no manifest.csv")
    if fz_pressing not in ("auto", "positive", "negative"):
        raise ValueError(f"fz_pressing must be 'auto', 'positive' or 'negative', got {fz_pressing!r}")
    meta = json.loads((root / "meta.json").read_text()) if (root / "meta.json").is_file() else {}
    records = []
    with open(manifest, newline="") as f:
        for line, row in enumerate(csv.DictReader(f), start=2):
            image = _field(row, "image", line, str)
            force = tuple(_field(row, k, line, float) for k in ("fx", "fy", "fz"))
            pose = tuple(float(row.get(k) or 0.0) for k in ("x_mm", "y_mm", "theta_rad"))
            records.append(TactileRecord(image, _field(row, "object", line, str), _field(row, "pose_id", line, int), pose, force))
    if not records:
        raise ValueError(f"{manifest} has no rows")
    sign = fz_pressing if fz_pressing != "auto" else meta.get("fz_pressing")
    if sign is None:
        sign = "negative" if np.median([r.force[2] for r in records]) < 0 else "positive"
    if sign == "negative":
        records = [TactileRecord(r.image, r.object, r.pose_id, r.pose, (r.force[0], r.force[1], -r.force[2])) for r in records]
    bg_path = root / "background.png"
    background = cv2.cvtColor(cv2.imread(str(bg_path)), cv2.COLOR_BGR2RGB) if bg_path.is_file() else None
    return TactileDataset(root, records, background, meta)


def main(argv=None) -> Path:
    p = argparse.ArgumentParser(
        prog="python -m controltac_il.tactile.dataset",
        description="Render a sensor-model tactile dataset (manifest.csv, background.png, meta.json, "
                    "images/<object>/). Every image is a pure function of the arguments; the folder appears "
                    "only when complete.")
    p.add_argument("--out", required=True, help="dataset folder to create (must not exist)")
    p.add_argument("--objects", nargs="+", default=list(TRAIN_OBJECTS), choices=sorted(INDENTERS), metavar="NAME",
                   help=f"indenters to press (default: the six training objects {' '.join(TRAIN_OBJECTS)})")
    d = {k: v.default for k, v in inspect.signature(write_dataset).parameters.items()}
    p.add_argument("--poses-per-object", type=int, default=d["poses_per_object"],
                   help=f"contact poses per object (default {d['poses_per_object']})")
    p.add_argument("--forces-per-pose", type=int, default=d["forces_per_pose"],
                   help=f"forces rendered at each pose (default {d['forces_per_pose']})")
    p.add_argument("--seed", type=int, default=d["seed"], help=f"seeds poses, forces and sensor noise (default {d['seed']})")
    p.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=None,
                   help="render resolution in pixels, same pad (default: GelSight Mini's native 240 320)")
    p.add_argument("--optics", choices=("three_light", "polynomial"), default=d["optics"],
                   help=f"sensor optics model (default {d['optics']})")
    p.add_argument("--fz-range", type=float, nargs=2, metavar=("LOW", "HIGH"), default=d["fz_range"],
                   help="normal force range in N, drawn uniformly (default {} {})".format(*d["fz_range"]))
    p.add_argument("--shear-max", type=float, default=d["shear_max"],
                   help=f"|Fx|, |Fy| bound in N (default {d['shear_max']})")
    a = p.parse_args(argv)
    if Path(a.out).exists():
        p.error(f"--out {a.out} exists; choose a new folder (datasets are never overwritten)")
    try:
        spec = SensorSpec.gelsight_mini()
        if a.size is not None:
            spec = spec.scaled(*a.size)
        out = write_dataset(a.out, a.objects, a.poses_per_object, a.forces_per_pose, a.seed, spec, a.optics,
                            tuple(a.fz_range), a.shear_max)
    except ValueError as e:
        p.error(str(e))
    print(f"wrote {out} ({len(a.objects) * a.poses_per_object * a.forces_per_pose} images)")
    return out


if __name__ == "__main__":
    main()
