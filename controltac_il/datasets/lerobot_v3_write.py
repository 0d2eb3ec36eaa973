"""Writing the pieces of a LeRobot v3.0 folder (facts: ``docs/lerobot_v3_format.md``), each file atomically:
data parquet files (one row group per episode), mp4 videos in a source's codec, per-episode and dataset stats as
LeRobot computes them, ``meta/episodes``, ``meta/stats.json`` and ``meta/info.json`` (exactly the keys of
LeRobot main's typed ``DatasetInfo``, which drops any other on a rewrite; lerobot 0.4.4 reads the same keys).

Stats follow LeRobot 0.4.4 (``compute_stats.py``): per episode min, max, mean, std, count and the quantiles
``QUANTILES`` of every feature; cameras per channel as (3, 1, 1) lists in [0, 1] over the frames
``sample_indices`` picks (strided when the long side is >= 300 px), count = frames sampled; across episodes
count-weighted means, pooled variance, min of mins, max of maxes, quantiles as the count-weighted mean of the
episodes'. Two departures, both in LeRobot's favour: camera std in float (0.4.4 squares uint8 and overflows,
huggingface/lerobot#3682) and exact per-episode quantiles (LeRobot bins a 5000-bin histogram).
"""

from __future__ import annotations

import json
import os
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from controltac_il.datasets.lerobot_v3_video import readable
from controltac_il.io import atomic_path, write_json

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
STAT_NAMES = ("min", "max", "mean", "std", "count", *(f"q{round(q * 100):02d}" for q in QUANTILES))
# encoder and settings per source codec: LeRobot's g=2 (a keyframe every 2 frames) and SVT-AV1 preset 12, a lower
# crf than its 30 as generated frames are encoded once more after the generator's own error (round trip measured
# per write; preset 8 costs twice the time for a round trip MSE 4 % lower on the scene's 120x160 frames)
ENCODERS = {"av1": ("libsvtav1", {"crf": "10", "g": "2", "preset": "12"}),
            "h264": ("libx264", {"crf": "10", "g": "2"}),
            "hevc": ("libx265", {"crf": "10", "g": "2"})}
FALLBACK = "h264"  # a source codec without an encoder here (or none known) is written as this
EPISODES_META = Path("meta/episodes/chunk-000/file-000.parquet")
# meta/info.json: the fields of LeRobot main's DatasetInfo (datasets/utils.py) in lerobot 0.4.4's order, the
# defaults of both where one is missing (0.4.4 reads robot_type and the storage settings with no default of its own)
INFO_KEYS = ("codebase_version", "robot_type", "total_episodes", "total_frames", "total_tasks", "chunks_size",
             "data_files_size_in_mb", "video_files_size_in_mb", "fps", "splits", "data_path", "video_path", "features")
INFO_DEFAULTS = {"robot_type": None, "chunks_size": 1000, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
                 "splits": {}, "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
                 "video_path": None}
OPTIONAL_INFO = ("tools",)  # main only: written where set (main's DatasetInfo.to_dict drops a null one)


def png_bytes(rgb: np.ndarray) -> bytes:
    """PNG of an RGB uint8 (H, W, 3) image (LeRobot's image feature bytes)."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise ValueError("could not encode a PNG")
    return buf.tobytes()


def write_parquet(path: Path, table: pa.Table) -> None:
    """``table`` as one row group, snappy (meta/episodes, one row per episode, as LeRobot writes it), atomically."""
    with atomic_path(path, ".parquet") as tmp:
        pq.write_table(table, tmp, row_group_size=max(len(table), 1), compression="snappy")


def write_data_parquet(path: Path, table: pa.Table) -> None:
    """Data rows as one row group per episode, snappy, atomically: lerobot 0.4.4's recorder writes one per episode
    and main (#3807, ``io_utils.write_table_one_row_group_per_episode``) requires it. ValueError when an
    episode's rows are not contiguous."""
    episodes = table.column("episode_index").to_numpy()
    starts = np.flatnonzero(np.diff(episodes, prepend=-1))
    if len(set(episodes[starts].tolist())) < len(starts):
        raise ValueError(f"dataset: the rows of an episode are not contiguous in the data of {path}")
    stops = np.append(starts[1:], len(table))
    with atomic_path(path, ".parquet") as tmp, pq.ParquetWriter(tmp, table.schema, compression="snappy") as writer:
        for a, b in zip(starts.tolist(), stops.tolist()):
            writer.write_table(table.slice(a, b - a), row_group_size=b - a)


def video_codec(path: Path) -> tuple[str, str]:
    """(codec name as the stream reports it, pix_fmt) of an mp4's first video stream."""
    with readable(path), av.open(str(path), metadata_errors="ignore") as container:
        ctx = container.streams.video[0].codec_context
        return ctx.name, ctx.pix_fmt or "yuv420p"


def encoder_for(codec: str) -> tuple[str, str, dict]:
    """(codec written, encoder, options) for a source ``codec``: the same where an encoder is here, else FALLBACK."""
    name = codec if codec in ENCODERS and ENCODERS[codec][0] in av.codecs_available else FALLBACK
    encoder, options = ENCODERS[name]
    return name, encoder, dict(options)


def encode_video(path: Path, frames: np.ndarray, fps: int, codec: str, pix_fmt: str = "yuv420p") -> str:
    """Encode RGB uint8 (T, H, W, 3) as an mp4, frame k at k / fps s; returns the codec written."""
    name, encoder, options = encoder_for(codec)
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only, not its banner per file
    with atomic_path(path, ".mp4") as tmp, av.open(str(tmp), "w", format="mp4") as container:
        stream = container.add_stream(encoder, rate=fps)
        stream.height, stream.width = frames.shape[1:3]
        stream.pix_fmt, stream.options = pix_fmt, options
        for k, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts, frame.time_base = k, Fraction(1, fps)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return name


def decode_video(path: Path) -> np.ndarray:
    """Every frame of an mp4's first video stream, RGB uint8 (T, H, W, 3), in presentation order."""
    with readable(path), av.open(str(path), metadata_errors="ignore") as container:
        container.streams.video[0].thread_type = "AUTO"  # no fork follows: FFmpeg's threads are safe here
        frames = [(f.pts, f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]
    return np.stack([img for _, img in sorted(frames, key=lambda x: x[0])])


# --- stats ----------------------------------------------------------------------------------------

def sample_indices(length: int) -> np.ndarray:
    """Frames of an episode of ``length`` whose images enter its stats (LeRobot's rule)."""
    n = length if length < 100 else max(100, min(int(length ** 0.75), 10000))
    return np.round(np.linspace(0, length - 1, n)).astype(int)


def image_stats(frames: np.ndarray) -> dict:
    """Stats of RGB uint8 (n, H, W, 3) sampled frames: per channel, (3, 1, 1) lists in [0, 1]."""
    return histogram_stats(frame_histograms(frames).sum(0), len(frames))


def frame_histograms(frames: np.ndarray) -> np.ndarray:
    """int64 (n, 3, 256): each channel's histogram of each of RGB uint8 (n, H, W, 3) frames, over the pixels
    their stats read (strided when the long side is >= 300 px). Summed over frames they give ``image_stats``
    exactly, so the histogram of a frame several episodes hold (a copy's unchanged frames) is computed once."""
    long_side = max(frames.shape[1:3])
    stride = int(long_side / 150) if long_side >= 300 else 1
    out = np.zeros((len(frames), 3, 256), np.int64)
    for i, frame in enumerate(frames[:, ::stride, ::stride]):
        for c in range(3):
            out[i, c] = np.bincount(frame[..., c].ravel(), minlength=256)
    return out


def histogram_stats(counts: np.ndarray, frames: int) -> dict:
    """Stats of ``frames`` sampled frames from their summed channel histograms int (3, 256) (``image_stats``)."""
    stats = [_channel_stats(counts[c]) for c in range(3)]
    out = {k: [[[st[k] / 255.0]] for st in stats] for k in STAT_NAMES if k != "count"}
    return {**out, "count": [int(frames)]}


def _channel_stats(counts: np.ndarray) -> dict:
    """min, max, mean, std and quantiles (as ``np.quantile``'s linear rule) of uint8 values given by their
    256-bin histogram (256,): exact, and without sorting."""
    counts = counts.astype(np.float64)
    levels = np.arange(256, dtype=np.float64)
    n = counts.sum()
    mean = float((counts * levels).sum() / n)
    out = {"min": float(np.flatnonzero(counts)[0]), "max": float(np.flatnonzero(counts)[-1]), "mean": mean,
           "std": float(np.sqrt((counts * (levels - mean) ** 2).sum() / n))}
    upto = np.cumsum(counts)  # upto[v]: values <= v
    for q in QUANTILES:
        pos = q * (n - 1)
        lo, hi = (int(np.searchsorted(upto, k, side="right")) for k in (np.floor(pos), np.ceil(pos)))
        out[f"q{round(q * 100):02d}"] = lo + (hi - lo) * (pos - np.floor(pos))
    return out


def vector_stats(values: np.ndarray, name: str) -> dict:
    """Stats of a numeric column (N,) or (N, D): lists of D (of 1 for scalars); integers' min / max stay ints."""
    values = np.asarray(values)
    if values.dtype.kind == "f" and not np.isfinite(values).all():
        raise ValueError(f"dataset: feature {name!r} holds NaN or inf; refusing to write stats of it")
    as_2d = values.reshape(len(values), -1)
    stats = _stats(as_2d.astype(np.float64))
    out = {k: np.asarray(stats[k]).tolist() for k in STAT_NAMES if k != "count"}
    if values.dtype.kind in "iub":
        out["min"], out["max"] = as_2d.min(0).astype(int).tolist(), as_2d.max(0).astype(int).tolist()
    return {**out, "count": [len(values)]}


def _stats(x: np.ndarray) -> dict:
    """min, max, mean, std and quantiles over the rows of (N, D) float64."""
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    for q, v in zip(QUANTILES, np.quantile(x, QUANTILES, axis=0)):
        out[f"q{round(q * 100):02d}"] = v
    return out


def complete_stats(stats: dict | None, feature: dict) -> bool:
    """Whether ``stats`` (one episode's of ``feature``, as meta/episodes holds them) has every stat of
    STAT_NAMES, finite, of the feature's shape ((3, 1, 1) a camera's, else the feature's size), count > 0,
    min <= mean <= max, and a camera's in [0, 1] (as LeRobot's and ours)."""
    if not stats or any(k not in stats for k in STAT_NAMES):
        return False
    camera = feature["dtype"] in ("image", "video")
    shape = (3, 1, 1) if camera else (int(np.prod(feature["shape"])),)
    try:
        values = {k: np.asarray(stats[k], np.float64) for k in STAT_NAMES if k != "count"}
        count = np.asarray(stats["count"], np.float64)
    except (TypeError, ValueError):
        return False
    if count.shape != (1,) or not count[0] > 0 or any(v.shape != shape or not np.isfinite(v).all()
                                                      for v in values.values()):
        return False
    lo, mean, hi = values["min"], values["mean"], values["max"]
    return bool(np.all(lo <= mean) and np.all(mean <= hi) and (not camera or (np.all(lo >= 0) and np.all(hi <= 1))))


def aggregate_stats(episodes: list[dict]) -> dict:
    """Dataset stats {feature: {stat: list}} from per-episode stats (module docstring)."""
    out = {}
    for key in episodes[0]:
        per = [ep[key] for ep in episodes]
        count = np.array([p["count"][0] for p in per], np.float64)
        w = (count / count.sum()).reshape(-1, *([1] * np.asarray(per[0]["mean"]).ndim))
        mean = np.stack([np.asarray(p["mean"], np.float64) for p in per])
        std = np.stack([np.asarray(p["std"], np.float64) for p in per])
        total_mean = (w * mean).sum(0)
        variance = (w * (std ** 2 + (mean - total_mean) ** 2)).sum(0)
        agg = {"min": np.min([p["min"] for p in per], 0), "max": np.max([p["max"] for p in per], 0),
               "mean": total_mean, "std": np.sqrt(variance), "count": [int(count.sum())]}
        for q in STAT_NAMES[5:]:
            agg[q] = (w * np.stack([np.asarray(p[q], np.float64) for p in per])).sum(0)
        out[key] = {k: (v if isinstance(v, list) else v.tolist()) for k, v in agg.items()}
    return out


# --- meta -----------------------------------------------------------------------------------------

def episodes_table(rows: list[dict]) -> pa.Table:
    """meta/episodes rows (one dict per episode, LeRobot's columns; ``stats`` as {feature: {stat: list}})."""
    flat = []
    for row in rows:
        stats = row.get("stats", {})
        out = {k: v for k, v in row.items() if k != "stats"}
        out.update({f"stats/{f}/{s}": v for f, st in stats.items() for s, v in st.items()})
        out["meta/episodes/chunk_index"], out["meta/episodes/file_index"] = 0, 0
        flat.append(out)
    return pa.Table.from_pylist(flat)


def info_json(info: dict) -> dict:
    """``info`` as meta/info.json holds it: exactly the fields of LeRobot main's ``DatasetInfo`` (any other is
    dropped, as main drops it on load and rewrite), a missing optional one at its default; KeyError for a missing
    codebase_version, total, fps or features."""
    out = {k: info[k] if k in info else INFO_DEFAULTS[k] for k in INFO_KEYS}
    return {**out, **{k: info[k] for k in OPTIONAL_INFO if info.get(k) is not None}}


def write_meta(root: Path, info: dict, rows: list[dict], stats: dict) -> None:
    """meta/episodes (one file), meta/stats.json and, last, meta/info.json (``info_json(info)``) of a folder whose
    data is written."""
    write_parquet(root / EPISODES_META, episodes_table(rows))
    write_json(root / "meta" / "stats.json", stats)
    with atomic_path(root / "meta" / "info.json", ".json") as tmp:
        tmp.write_text(json.dumps(info_json(info), indent=4))
