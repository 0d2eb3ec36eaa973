"""Tactile datasets in the FeelAnyForce layout: images plus a CSV manifest, one row per image.

Layout of a dataset folder::

    manifest.csv     image, object, pose_id, x_mm, y_mm, theta_rad, fx, fy, fz
    background.png   the sensor's no-contact frame (RGB PNG)
    meta.json        generator settings (spec, optics, seed, counts, force convention)
    images/<object>/<pose_id>_<k>.png
    backgrounds/<sensor>.png   with sensor randomisation: each instance's no-contact frame (manifest column
                               ``sensor``; then background.png is absent)

Forces are stored in the project's convention (N, sensor frame, Fz > 0 pressing). Real FeelAnyForce
recordings store Fz < 0 when pressing; ``load_dataset`` detects that (or is told) and flips the sign.

Command line (the generator's and estimator's training data)::

    python -m controltac_il.tactile.dataset --out data/train600 --poses-per-object 600 --seed 0 --size 120 160
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import inspect
import json
import numbers
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from tqdm.auto import tqdm

from controltac_il.cli import ArgumentParser
from controltac_il.config import is_int
from controltac_il.io import atomic_dir, unwritable
from controltac_il.tactile.indenters import INDENTERS, TRAIN_OBJECTS, get_indenter, procedural_objects
from controltac_il.tactile.instances import FAMILIES, sensor_instance
from controltac_il.tactile.residual import to_residual
from controltac_il.tactile.spec import IMAGE_SIDE_PX, MAX_PLAUSIBLE_FORCE_N, SensorSpec

if TYPE_CHECKING:  # the sensor model (OpenCV) is imported where images are rendered: --help stays light
    from controltac_il.tactile.sensor import TactileSensor

MANIFEST_FIELDS = ("image", "object", "pose_id", "x_mm", "y_mm", "theta_rad", "fx", "fy", "fz")
SENSOR_FIELD = "sensor"  # optional: the simulated sensor instance of the row (controltac_il.tactile.instances)
FZ_RANGE = (0.5, 11.0)  # N: the rendered training forces, a margin around the validated 1-10 N
SHEAR_MAX = 1.0  # N: |Fx|, |Fy| of the rendered training forces


@dataclass(frozen=True)
class TactileRecord:
    """One manifest row: the image path (relative to the dataset), the contact pose and force (N), and the
    sensor instance that rendered it (None: the dataset's one sensor)."""

    image: str
    object: str
    pose_id: int
    pose: tuple[float, float, float]
    force: tuple[float, float, float]
    sensor: str | None = None


def sample_contacts(objects: Sequence[str], poses_per_object: int, forces_per_pose: int, seed: int,
                    spec: SensorSpec, fz_range=FZ_RANGE, shear_max: float = SHEAR_MAX, only: int | None = None):
    """Deterministic contact list: each (object, pose) draws from its own stream keyed by (seed, object index, pose).

    Yields (object, pose_id, pose (x, y, θ), [(fx, fy, fz), ...], noise seeds); ``only``: that object index alone.
    """
    half_h, half_w = (s / 2 for s in spec.pad_size_mm)
    for oi, name in enumerate(objects):
        if only is not None and oi != only:
            continue
        get_indenter(name)
        for pid in range(poses_per_object):
            rng = np.random.default_rng([seed, oi, pid])
            pose = (rng.uniform(-0.6, 0.6) * half_w, rng.uniform(-0.6, 0.6) * half_h, rng.uniform(0, np.pi))
            fz = rng.uniform(*fz_range, size=forces_per_pose)
            fxy = rng.uniform(-shear_max, shear_max, size=(forces_per_pose, 2))
            forces = [(float(a), float(b), float(c)) for (a, b), c in zip(fxy, fz)]
            noise = rng.integers(0, 2**31, size=forces_per_pose)
            yield name, pid, pose, forces, [int(n) for n in noise]


def _check_replaceable(out_dir: Path) -> None:
    """``out_dir`` is new, empty, or a dataset this writer wrote (manifest.csv and meta.json with its "spec"), the
    only folder it replaces; ValueError naming it otherwise (never replace the user's files)."""
    if not out_dir.exists() or (out_dir.is_dir() and not any(out_dir.iterdir())):
        return
    try:
        ours = (out_dir / "manifest.csv").is_file() and "spec" in json.loads((out_dir / "meta.json").read_text())
    except (OSError, ValueError, TypeError):
        ours = False
    if not ours:
        raise ValueError(f"out_dir: {out_dir} holds files this writer did not write (a rendered dataset has "
                         "manifest.csv and meta.json); give a new or empty folder")


def _check_write_args(objects: tuple, poses_per_object, forces_per_pose, seed, fz_range, shear_max, sensors,
                      instances) -> None:
    """ValueError naming the first bad argument of :func:`write_dataset`."""
    if not objects or len(set(objects)) != len(objects):
        raise ValueError(f"objects must name each indenter once (images are stored per object), got {list(objects)}")
    for name in objects:
        get_indenter(name)
    for name, value in (("poses_per_object", poses_per_object), ("forces_per_pose", forces_per_pose)):
        if not is_int(value) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    if not is_int(seed) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}")
    try:
        lo, hi = (float(v) for v in fz_range)
    except (TypeError, ValueError):
        lo = hi = float("nan")
    if not (np.isfinite([lo, hi]).all() and 0 <= lo < hi <= MAX_PLAUSIBLE_FORCE_N):
        raise ValueError(f"fz_range must be (low, high) finite with 0 <= low < high <= {MAX_PLAUSIBLE_FORCE_N:g} N, "
                         f"got {fz_range!r}")
    if not (isinstance(shear_max, numbers.Real) and not isinstance(shear_max, bool) and np.isfinite(shear_max)
            and 0 <= shear_max <= MAX_PLAUSIBLE_FORCE_N):
        raise ValueError(f"shear_max must be a finite number in [0, {MAX_PLAUSIBLE_FORCE_N:g}] N, got {shear_max!r}")
    if sensors is not None and not (sensors in FAMILIES and is_int(instances) and instances >= 1):
        raise ValueError(f"sensors must be None or one of {FAMILIES} with instances >= 1, got {sensors!r}, {instances!r}")


def write_dataset(out_dir, objects: Sequence[str] = TRAIN_OBJECTS, poses_per_object: int = 50,
                  forces_per_pose: int = 8, seed: int = 0, spec: SensorSpec | None = None,
                  optics: str = "three_light", fz_range=FZ_RANGE, shear_max: float = SHEAR_MAX,
                  progress: bool = True, sensors: str | None = None, instances: int = 16, workers: int = 1) -> Path:
    """Render a sensor-model dataset into ``out_dir`` (built in a temporary folder, renamed when complete).

    Every image is a pure function of (seed, object, pose_id, k): the same arguments give the same files, whatever
    ``workers`` (processes rendering whole objects at once; 1 = this process).
    sensors: None renders every image with ``spec`` and ``optics``; a family of
    ``controltac_il.tactile.instances`` ("train" | "unseen") renders each contact pose with one of its first
    ``instances`` sensor instances, drawn per pose (``spec`` then only gives the size).
    """
    import cv2

    objects = tuple(objects)
    _check_write_args(objects, poses_per_object, forces_per_pose, seed, fz_range, shear_max, sensors, instances)
    if not is_int(workers) or workers < 1:
        raise ValueError(f"workers must be an int >= 1, got {workers!r}")
    spec = spec or SensorSpec.gelsight_mini()
    out_dir = Path(out_dir)
    _check_replaceable(out_dir)
    total = len(objects) * poses_per_object * forces_per_pose
    job = _RenderJob(objects, poses_per_object, forces_per_pose, seed, spec, optics, tuple(fz_range), shear_max,
                     sensors, instances)
    with atomic_dir(out_dir) as tmp:
        if sensors is None:
            background = _sensor(spec, optics).background
            cv2.imwrite(str(tmp / "background.png"), cv2.cvtColor(background, cv2.COLOR_RGB2BGR))
        rows, used = _render_all(tmp, job, workers, f"rendering {out_dir.name}" if progress else None)
        for name, which in used.items():  # each instance's no-contact frame, written once by this process
            (tmp / "backgrounds").mkdir(exist_ok=True)
            inst = sensor_instance(sensors, which, (spec.height, spec.width))
            cv2.imwrite(str(tmp / "backgrounds" / f"{name}.png"),
                        cv2.cvtColor(_sensor(inst.spec, inst.optics).background, cv2.COLOR_RGB2BGR))
        with open(tmp / "manifest.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(MANIFEST_FIELDS + ((SENSOR_FIELD,) if sensors is not None else ()))
            w.writerows(rows)
        meta = {"spec": spec.to_dict(), "optics": optics, "seed": seed, "objects": list(objects),
                "poses_per_object": poses_per_object, "forces_per_pose": forces_per_pose,
                "fz_range": list(fz_range), "shear_max": shear_max, "fz_pressing": "positive", "count": total}
        if sensors is not None:  # spec and optics then give only the size; each row names its instance
            meta.update(sensors=sensors, instances=instances, sensor_names=sorted(used))
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
    return out_dir


@dataclass(frozen=True)
class _RenderJob:
    """The arguments of :func:`write_dataset` that decide the images (picklable, for worker processes)."""

    objects: tuple
    poses_per_object: int
    forces_per_pose: int
    seed: int
    spec: SensorSpec
    optics: str
    fz_range: tuple
    shear_max: float
    sensors: str | None
    instances: int


def _render_all(tmp: Path, job: _RenderJob, workers: int, desc: str | None) -> tuple[list[list], dict[str, int]]:
    """Every object of ``job`` rendered under ``tmp/images``, by ``workers`` processes (one object per task); the
    manifest rows in object order and the sensor instances used ({name: index})."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    per_object = job.poses_per_object * job.forces_per_pose
    results: list = [None] * len(job.objects)
    with tqdm(total=per_object * len(job.objects), desc=desc, unit="img", disable=True if desc is None else None) as bar:
        if workers == 1:
            for oi in range(len(job.objects)):
                results[oi] = _render_object(tmp, job, oi)
                bar.update(per_object)
        else:
            pool = ProcessPoolExecutor(min(workers, len(job.objects)))
            try:
                futures = {pool.submit(_render_object, tmp, job, oi): oi for oi in range(len(job.objects))}
                for future in as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update(per_object)
            finally:  # a failed object or Ctrl-C: the objects not started are dropped, not rendered first
                pool.shutdown(cancel_futures=True)
    rows, used = [], {}
    for object_rows, object_used in results:
        rows += object_rows
        used.update(object_used)
    return rows, used


@functools.lru_cache(maxsize=64)
def _sensor(spec: SensorSpec, optics: str) -> "TactileSensor":
    """This process's sensor model for ``spec`` and ``optics``, built once (5 ms each; a dataset of 120 objects
    draws its 24 instances per object)."""
    from controltac_il.tactile.sensor import TactileSensor

    return TactileSensor(spec, optics=optics)


def _render_object(tmp: Path, job: _RenderJob, oi: int) -> tuple[list[list], dict[str, int]]:
    """Press every (pose, force) of object ``job.objects[oi]`` and write its PNGs; its manifest rows and the sensor
    instances it used ({name: index})."""
    import cv2

    name, spec = job.objects[oi], job.spec
    (tmp / "images" / name).mkdir(parents=True, exist_ok=True)
    sensor = _sensor(spec, job.optics) if job.sensors is None else None
    rows, used = [], {}
    contacts = sample_contacts(job.objects, job.poses_per_object, job.forces_per_pose, job.seed, spec, job.fz_range,
                               job.shear_max, only=oi)
    for _, pid, pose, forces, noise in contacts:
        if job.sensors is not None:
            which = int(np.random.default_rng([job.seed, oi, pid, 9]).integers(job.instances))
            inst = sensor_instance(job.sensors, which, (spec.height, spec.width))
            used[inst.name] = which
            sensor = _sensor(inst.spec, inst.optics)
        for k, (force, ns) in enumerate(zip(forces, noise)):
            c = sensor.press(name, pose, force, noise_seed=ns)
            rel = f"images/{name}/{pid:04d}_{k:02d}.png"
            cv2.imwrite(str(tmp / rel), cv2.cvtColor(c.image, cv2.COLOR_RGB2BGR))
            rows.append([rel, name, pid, *(f"{v:.6f}" for v in pose), *(f"{v:.6f}" for v in c.force)]
                        + ([inst.name] if job.sensors is not None else []))
    return rows, used


class TactileDataset:
    """A loaded dataset folder: records, images and residuals (uint8 RGB (H, W, 3))."""

    def __init__(self, root: Path, records: list[TactileRecord], background: np.ndarray | None, meta: dict,
                 backgrounds: dict[str, np.ndarray] | None = None):
        self.root, self.records, self.background, self.meta = root, records, background, meta
        self.backgrounds = backgrounds or {}  # per sensor instance (sensor randomisation)

    def __len__(self) -> int:
        return len(self.records)

    def image(self, i: int) -> np.ndarray:
        import cv2

        path = self.root / self.records[i].image
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"manifest row {i}: cannot read image {path}")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def background_of(self, i: int) -> np.ndarray:
        """The no-contact frame of record ``i``'s sensor, uint8 (H, W, 3)."""
        sensor = self.records[i].sensor
        bg = self.background if sensor is None else self.backgrounds.get(sensor)
        if bg is None:
            where = "background.png" if sensor is None else f"backgrounds/{sensor}.png"
            raise ValueError(f"{self.root} has no {where}: residuals need the no-contact frame")
        return bg

    def residual(self, i: int) -> np.ndarray:
        return to_residual(self.image(i), self.background_of(i))

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
    try:
        meta = json.loads((root / "meta.json").read_text()) if (root / "meta.json").is_file() else {}
    except json.JSONDecodeError as exc:
        raise ValueError(f"{root / 'meta.json'}: not valid JSON ({exc})") from None
    records = []
    with open(manifest, newline="") as f:
        for line, row in enumerate(csv.DictReader(f), start=2):
            image = _field(row, "image", line, str)
            force = tuple(_field(row, k, line, float) for k in ("fx", "fy", "fz"))
            pose = tuple(_field(row, k, line, float) if row.get(k) else 0.0 for k in ("x_mm", "y_mm", "theta_rad"))
            records.append(TactileRecord(image, _field(row, "object", line, str), _field(row, "pose_id", line, int), pose,
                                         force, row.get(SENSOR_FIELD) or None))
    if not records:
        raise ValueError(f"{manifest} has no rows")
    sign = fz_pressing if fz_pressing != "auto" else meta.get("fz_pressing")
    if sign is None:
        sign = "negative" if np.median([r.force[2] for r in records]) < 0 else "positive"
    if sign == "negative":
        records = [dataclasses.replace(r, force=(r.force[0], r.force[1], -r.force[2])) for r in records]
    import cv2

    def read(path):  # None where absent; a file that is not an image is named
        if not path.is_file():
            return None
        img = cv2.imread(str(path))
        if img is None:
            raise ValueError(f"{path}: not a readable image (a background must be a PNG)")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    backgrounds = {n: read(root / "backgrounds" / f"{n}.png") for n in {r.sensor for r in records} - {None}}
    missing = sorted(n for n, bg in backgrounds.items() if bg is None)
    if missing:
        raise ValueError(f"{root}: manifest names sensor instances without backgrounds/<sensor>.png: {missing}")
    return TactileDataset(root, records, read(root / "background.png"), meta, backgrounds)


def _parser() -> ArgumentParser:
    p = ArgumentParser(
        prog="python -m controltac_il.tactile.dataset",
        description="Render a sensor-model tactile dataset (manifest.csv, background.png, meta.json, "
                    "images/<object>/). Every image is a pure function of the arguments; the folder appears "
                    "only when complete.")
    p.add_argument("--out", required=True, help="dataset folder to create (must not exist)")
    p.add_argument("--objects", nargs="+", default=list(TRAIN_OBJECTS), choices=sorted(INDENTERS), metavar="NAME",
                   help=f"indenters to press, each once (default: the six training objects {' '.join(TRAIN_OBJECTS)})")
    p.add_argument("--procedural", type=int, default=0, metavar="N",
                   help="also press N random training shapes procedural_0000 ... (object diversity; default 0)")
    d = {k: v.default for k, v in inspect.signature(write_dataset).parameters.items()}
    p.add_argument("--poses-per-object", type=int, default=d["poses_per_object"],
                   help=f"contact poses per object, >= 1 (default {d['poses_per_object']})")
    p.add_argument("--forces-per-pose", type=int, default=d["forces_per_pose"],
                   help=f"forces rendered at each pose, >= 1 (default {d['forces_per_pose']})")
    p.add_argument("--seed", type=int, default=d["seed"],
                   help=f"seeds poses, forces and sensor noise, >= 0 (default {d['seed']})")
    p.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=None,
                   help=f"render resolution in pixels, {IMAGE_SIDE_PX[0]}-{IMAGE_SIDE_PX[1]} at the pad's 3:4 "
                        "aspect, same pad (default: GelSight Mini's native 240 320)")
    p.add_argument("--optics", choices=("three_light", "polynomial"), default=None,
                   help=f"sensor optics model of the one sensor, without --sensors (default {d['optics']})")
    p.add_argument("--sensors", choices=FAMILIES, default=None,
                   help="sensor randomisation: render each contact pose with one instance of this family "
                        "(controltac_il.tactile.instances; 'unseen' is held out of training); default: one sensor, --optics")
    p.add_argument("--instances", type=int, default=None,
                   help=f"only with --sensors: how many of the family's instances to draw from, >= 1 (default {d['instances']})")
    p.add_argument("--fz-range", type=float, nargs=2, metavar=("LOW", "HIGH"), default=d["fz_range"],
                   help="normal force range in N, 0 <= LOW < HIGH, drawn uniformly (default {} {})".format(*d["fz_range"]))
    p.add_argument("--shear-max", type=float, default=d["shear_max"],
                   help=f"|Fx|, |Fy| bound in N, in [0, {MAX_PLAUSIBLE_FORCE_N:g}] (default {d['shear_max']})")
    p.add_argument("--workers", type=int, default=d["workers"],
                   help="processes rendering whole objects at once; the files are the same for any number "
                        f"(default {d['workers']})")
    return p


def main(argv=None) -> Path:
    p = _parser()
    a = p.parse_args(argv)
    if Path(a.out).exists():
        p.error(f"--out {a.out} exists; choose a new folder (datasets are never overwritten)")
    why = unwritable(a.out)
    if why:
        p.error(f"--out {a.out}: {why}")
    if len(set(a.objects)) != len(a.objects):
        p.error(f"--objects must name each indenter once, got {' '.join(a.objects)}")
    if a.procedural < 0:
        p.error(f"--procedural must be an int >= 0, got {a.procedural}")
    objects = [*a.objects, *procedural_objects(a.procedural)]
    for flag, value in (("--poses-per-object", a.poses_per_object), ("--forces-per-pose", a.forces_per_pose)):
        if value < 1:
            p.error(f"{flag} must be an int >= 1, got {value}")
    if a.seed < 0:
        p.error(f"--seed must be an int >= 0, got {a.seed}")
    if a.workers < 1:
        p.error(f"--workers must be an int >= 1, got {a.workers}")
    if a.instances is not None and a.sensors is None:
        p.error(f"--instances {a.instances}: the number of randomised sensors to draw from, used only with --sensors")
    if a.optics is not None and a.sensors is not None:
        p.error(f"--optics {a.optics}: the one sensor's optics; --sensors {a.sensors} draws each instance's own")
    a.optics = a.optics or inspect.signature(write_dataset).parameters["optics"].default
    lo, hi = a.fz_range
    if not (np.isfinite([lo, hi]).all() and 0 <= lo < hi <= MAX_PLAUSIBLE_FORCE_N):
        p.error(f"--fz-range LOW HIGH must be finite newtons with 0 <= LOW < HIGH <= {MAX_PLAUSIBLE_FORCE_N:g} "
                f"(a GelSight Mini is rated to about 25 N), got {lo:g} {hi:g}")
    if not (np.isfinite(a.shear_max) and 0 <= a.shear_max <= MAX_PLAUSIBLE_FORCE_N):
        p.error(f"--shear-max must be a finite number in [0, {MAX_PLAUSIBLE_FORCE_N:g}] N, got {a.shear_max:g}")
    spec = SensorSpec.gelsight_mini()
    if a.size is not None:
        try:
            spec = spec.scaled(*a.size)
        except ValueError:
            p.error(f"--size H W must be ints in {list(IMAGE_SIDE_PX)} at the pad's {spec.height}:{spec.width} "
                    f"aspect (e.g. 120 160), got {a.size[0]} {a.size[1]}")
    try:
        drawn = {} if a.instances is None else {"instances": a.instances}  # else write_dataset's default
        out = write_dataset(a.out, objects, a.poses_per_object, a.forces_per_pose, a.seed, spec, a.optics,
                            (lo, hi), a.shear_max, sensors=a.sensors, workers=a.workers, **drawn)
    except ValueError as e:
        p.error(str(e).splitlines()[0] if str(e).strip() else repr(e))
    print(f"wrote {out} ({len(objects) * a.poses_per_object * a.forces_per_pose} images)")
    return out


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m controltac_il.tactile.dataset", lambda: main() and 0,
                           "interrupted (Ctrl-C): nothing was written (the folder appears only when complete)"))
