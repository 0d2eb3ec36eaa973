"""Recordings of grasps and presses, as labs record them, turned into the presses layout ``calibrate`` reads.

A recordings folder holds one recording per name::

    <name>.mp4 (or .avi, .mov, .mkv)   the sensor's video, or
    <name>/                           its frames as images (PNG / JPG, in name order)
    <name>.csv                        one row per frame: ``fz`` (N; ``fx``, ``fy`` optional), header required

A recording may hold several presses. Each is a run of frames in contact (|Fz| >= ``contact_force``); its
loading ramp (from the run's first frame to its peak) is kept where the label lies in the generator's validated
Fz range, every ``stride``-th frame. The background is the per-pixel median of the recording's no-contact frames
(|Fz| < ``no_contact_force``): one per recording, so a session's lighting is its own. Labels may lag the video:
``lag`` shifts them (label[i] = force[i + lag]); ``lag="auto"`` picks, per recording, the shift in
[-MAX_LAG, MAX_LAG] frames that maximises the rank correlation between the frames' contact signal (the mean residual
above the contact gate: contact area weighted by depth, closer to linear in force than the area) and the force.
Fz < 0 while pressing (a load cell's convention) is flipped. A frame whose every value is 0 or 255 (dark,
overexposed or dropped) is left out of all of it, with a warning. Written layout: ``tactile.dataset``'s FeelAnyForce
layout, one contact pose per press (object = recording name), ``backgrounds/<name>.png``, Fx = Fy = 0 where the
CSV has no such column (``meta.json`` ``force_axes`` says which axes were measured).
"""

from __future__ import annotations

import csv
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from controltac_il.datasets.checks import check_newtons
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.io import atomic_dir
from controltac_il.tactile.residual import blank, residual_magnitude, to_residual
from controltac_il.calibrate.decision import MIN_GRASPS

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MAX_LAG = 3  # frames searched by lag="auto"
AREA_GATE = 8.0  # grey levels: a pixel deviating more from the background is in contact (the estimator's gate)


@dataclass(frozen=True)
class RecordingOptions:
    """How recordings are read: forces in N, lag in frames (int) or "auto", size (H, W) of the written frames."""

    size: tuple[int, int] = (240, 320)
    lag: int | str = 0
    contact_force: float = 0.5
    no_contact_force: float = 0.2
    stride: int = 1


def find_recordings(folder: Path) -> dict[str, tuple[Path, Path]]:
    """{name: (frames path, force CSV)} of every recording in ``folder``; ValueError naming what is missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"--recordings: {folder} is not a folder")
    found = {}
    for csv_path in sorted(folder.glob("*.csv")):
        stem = csv_path.stem
        frames = [p for p in (*(folder / (stem + s) for s in VIDEO_SUFFIXES), folder / stem) if p.exists()]
        if not frames:
            raise ValueError(f"{csv_path}: no video ({'/'.join(VIDEO_SUFFIXES)}) or frames folder named {stem!r} beside it")
        found[stem] = (frames[0], csv_path)
    if not found:
        raise ValueError(f"--recordings: {folder} holds no recording (a <name>.csv force log beside <name>.mp4 or <name>/)")
    return found


def read_frames(path: Path, size: tuple[int, int]) -> np.ndarray:
    """Frames uint8 RGB (T, H, W, 3) of a video file or an images folder, resized to ``size``; ValueError naming
    the file that cannot be read."""
    frames = []
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        for p in files:
            bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"{p}: not a readable image")
            frames.append(bgr)
    else:
        cap = cv2.VideoCapture(str(path))
        ok, bgr = cap.read()
        while ok:
            frames.append(bgr)
            ok, bgr = cap.read()
        cap.release()
    if not frames:
        raise ValueError(f"{path}: no frame could be read (not a video or image folder this machine decodes)")
    h, w = size
    return np.stack([cv2.cvtColor(cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
                     for f in frames])


def read_forces(path: Path) -> tuple[np.ndarray, list[str]]:
    """Forces float64 (T, 3) N from a CSV with a ``fz`` column (``fx``, ``fy`` optional), and the axes measured;
    Fz flipped when pressing reads negative. ValueError naming the file, line and column, or the file for forces
    beyond a GelSight's plausible range (a log in mN)."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        cols = {c.strip().lower(): c for c in reader.fieldnames or ()}
        if "fz" not in cols:
            raise ValueError(f"{path}: no 'fz' column (header: {reader.fieldnames})")
        axes = [a for a in ("fx", "fy", "fz") if a in cols]
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[cols[a]]) if a in cols else 0.0 for a in ("fx", "fy", "fz")])
            except (TypeError, ValueError):
                raise ValueError(f"{path} line {line}: a force that is not a number: {row}") from None
    forces = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(forces).all():
        raise ValueError(f"{path} line {2 + int(np.flatnonzero(~np.isfinite(forces).all(1))[0])}: a force that is not finite")
    check_newtons(str(path), forces)
    if len(forces) and np.median(forces[np.argsort(-np.abs(forces[:, 2]))[: max(1, len(forces) // 10)], 2]) < 0:
        forces[:, 2] = -forces[:, 2]
    return forces, axes


def shift(forces: np.ndarray, lag: int) -> np.ndarray:
    """Labels (T, 3) with the log shifted by ``lag`` frames: label[i] = forces[i + lag], held at the ends."""
    idx = np.clip(np.arange(len(forces)) + int(lag), 0, len(forces) - 1)
    return forces[idx]


def contact_signal(residual: np.ndarray) -> np.ndarray:
    """The contact signal ``lag="auto"`` aligns with the force: the mean residual above AREA_GATE (grey levels) of
    uint8 (..., H, W, 3) residuals, contact area weighted by depth; float64 (...)."""
    return np.maximum(residual_magnitude(residual) - AREA_GATE, 0).mean(axis=(-2, -1)).astype(np.float64)


def best_lag(signal: np.ndarray, fz: np.ndarray, max_lag: int = MAX_LAG, valid: np.ndarray | None = None) -> int:
    """The shift in [-max_lag, max_lag] frames maximising the rank (Spearman) correlation of contact signal[i] and
    Fz[i + lag] over the frames where both exist (no held ends) and ``valid[i]`` (bool (T,), default all); the
    smallest shift on ties, 0 for a flat signal.
    Ranks, because the signal grows with force by a sensor's own concave law: a linear correlation prefers the shift
    that straightens the curve (0 of 24 lags recovered on ``benchmarks.calibration``'s grasps, against 21)."""
    from scipy.stats import spearmanr

    n, scores = len(fz), {}
    for lag in range(-max_lag, max_lag + 1):
        i = np.arange(max(0, -lag), min(n, n - lag))
        i = i if valid is None else i[valid[i]]
        a, b = signal[i], fz[i + lag]
        ok = len(i) > 2 and np.ptp(a) > 0 and np.ptp(b) > 0
        scores[lag] = float(spearmanr(a, b).statistic) if ok else -np.inf
    best = max(scores.values())
    return 0 if best == -np.inf else min((lag for lag, s in scores.items() if s == best), key=abs)


def presses(fz: np.ndarray, contact_force: float) -> list[np.ndarray]:
    """Frame indices of each press's loading ramp: a run of |Fz| >= contact_force, from its start to its peak."""
    on = np.abs(fz) >= contact_force
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(int), 0]))
    out = []
    for start, stop in zip(edges[::2], edges[1::2]):
        peak = start + int(np.argmax(fz[start:stop]))
        out.append(np.arange(start, peak + 1))
    return out


@dataclass
class Recording:
    """One recording read and aligned: its background (H, W, 3), kept frames (N, H, W, 3) uint8, their labels
    (N, 3) N and press index (N,), the lag applied (frames) and the force axes its log measured."""

    name: str
    background: np.ndarray
    frames: np.ndarray
    labels: np.ndarray
    press: np.ndarray
    lag: int
    axes: list


def read_recording(name: str, frames_path: Path, csv_path: Path, opts: RecordingOptions) -> Recording:
    """Read, align and cut one recording (module docstring); ValueError naming the file for bad input."""
    frames = read_frames(frames_path, opts.size)
    forces, axes = read_forces(csv_path)
    if len(forces) != len(frames):
        raise ValueError(f"{csv_path}: {len(forces)} force rows for {len(frames)} frames in {frames_path.name}; "
                         "one row per frame is needed")
    if opts.lag != "auto" and abs(int(opts.lag)) >= len(frames):  # every label would be a held end of the log
        raise ValueError(f"--lag {opts.lag}: {csv_path.stem} has {len(frames)} frames; a lag must be shorter than "
                         "the recording (try --lag auto)")
    seen = ~blank(frames)  # a dark, overexposed or dropped frame shows nothing: in no background, ramp or lag
    if not seen.all():
        warnings.warn(f"{frames_path}: {int((~seen).sum())} of {len(frames)} frames have every value 0 or 255 (a "
                      "dark, overexposed or dropped camera frame); left out")
    free = np.abs((forces if opts.lag == "auto" else shift(forces, opts.lag))[:, 2]) < opts.no_contact_force
    if not (free & seen).any():
        raise ValueError(f"{csv_path}: no no-contact frame (|Fz| < {opts.no_contact_force:g} N) for the background")
    background = np.median(frames[free & seen], axis=0).round().astype(np.uint8)
    if opts.lag == "auto":
        signal = np.array([contact_signal(to_residual(f, background)) for f in frames])
        lag = best_lag(signal, forces[:, 2], valid=seen)
    else:
        lag = int(opts.lag)
    labels = shift(forces, lag)
    low, high = VALIDATED_RANGE.fz
    keep, press = [], []
    for p, ramp in enumerate(presses(labels[:, 2], opts.contact_force)):
        ramp = ramp[(labels[ramp, 2] >= low) & (labels[ramp, 2] <= high) & seen[ramp]][:: opts.stride]
        keep.append(ramp)
        press.append(np.full(len(ramp), p))
    rows = np.concatenate(keep) if keep else np.zeros(0, int)
    if not len(rows):
        raise ValueError(f"{csv_path}: no loading-ramp frame with Fz in the validated range [{low:g}, {high:g}] N")
    return Recording(name, background, frames[rows], labels[rows], np.concatenate(press), lag, axes)


def write_presses(recordings: list[Recording], out: Path) -> Path:
    """Write the recordings in the FeelAnyForce layout (module docstring) to ``out``, atomically."""
    with atomic_dir(out) as tmp:
        (tmp / "backgrounds").mkdir()
        rows = []
        for rec in recordings:
            cv2.imwrite(str(tmp / "backgrounds" / f"{rec.name}.png"), cv2.cvtColor(rec.background, cv2.COLOR_RGB2BGR))
            (tmp / "images" / rec.name).mkdir(parents=True)
            for k, (img, f, p) in enumerate(zip(rec.frames, rec.labels, rec.press)):
                rel = f"images/{rec.name}/{int(p)}_{k}.png"
                cv2.imwrite(str(tmp / rel), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
                rows.append({"image": rel, "object": rec.name, "pose_id": int(p), "x_mm": "", "y_mm": "",
                             "theta_rad": "", "fx": f[0], "fy": f[1], "fz": f[2], "sensor": rec.name})
        with open(tmp / "manifest.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        axes = [a for a in ("fx", "fy", "fz") if all(a in r.axes for r in recordings)]
        meta = {"source": "recordings", "fz_pressing": "positive", "force_axes": axes,
                "lags_frames": {r.name: r.lag for r in recordings}}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
    return out


def recordings_to_presses(folder: Path, out: Path, opts: RecordingOptions = RecordingOptions()) -> dict:
    """Read every recording in ``folder`` and write the presses layout to ``out``; a summary (per recording:
    frames kept, presses, lag)."""
    found = find_recordings(folder)
    recs = [read_recording(name, frames, forces, opts) for name, (frames, forces) in found.items()]
    summary = {r.name: {"frames": len(r.frames), "presses": len(np.unique(r.press)), "lag_frames": r.lag}
               for r in recs}  # distinct presses: a ramp emptied by the range filter keeps its number
    presses = sum(v["presses"] for v in summary.values())
    if presses < MIN_GRASPS:
        raise ValueError(f"{folder}: {presses} press{'' if presses == 1 else 'es'} in all recordings; at least "
                         f"{MIN_GRASPS} are needed (each is held out once to decide whether the estimator is used)")
    write_presses(recs, out)
    return summary
