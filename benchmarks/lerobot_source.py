"""A LeRobot v3.0 folder of the augment benchmark's recorded episodes, laid out as ``lerobot-record`` lays one
out: every episode in one data file (a row group each) and one mp4 per camera (episodes back to back, AV1 as
LeRobot's default). Tactile ``gelsight_left`` is an image feature (PNG in the parquet), ``gelsight_right`` a
video feature, the two RGB cameras videos; force labels under ``observation.gelsight_<s>.force``; per-episode
stats of every feature in ``meta/episodes`` and their aggregate in ``meta/stats.json``, as the recorder writes
them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa

from controltac_il.datasets.episodes import episode_paths, read_episode
from controltac_il.lerobot import (aggregate_stats, encode_video, image_stats, numbers, png_bytes, sample_indices,
                                   vector_stats, write_data_parquet, write_meta, write_parquet)
from controltac_il.streams import LEROBOT, LEROBOT_STATE, force_key, image_key, tactile_key

FPS = 10
IMAGE, VIDEO = tactile_key("gelsight_left", LEROBOT), tactile_key("gelsight_right", LEROBOT)
FORCES = {IMAGE: force_key("gelsight_left", LEROBOT), VIDEO: force_key("gelsight_right", LEROBOT)}
CAMERAS = ("third_view", "wrist")


def _features(tactile_shape, camera_shape) -> dict:
    cam = {"names": ["height", "width", "channels"]}
    scalar = {"shape": [1], "names": None}
    return {LEROBOT_STATE: {"dtype": "float32", "shape": [5], "names": None},
            "action": {"dtype": "float32", "shape": [5], "names": None},
            IMAGE: {"dtype": "image", "shape": list(tactile_shape), **cam},
            VIDEO: {"dtype": "video", "shape": list(tactile_shape), **cam},
            **{image_key(c, LEROBOT): {"dtype": "video", "shape": list(camera_shape), **cam} for c in CAMERAS},
            **{f: {"dtype": "float32", "shape": [3], "names": None} for f in FORCES.values()},
            "timestamp": {"dtype": "float32", **scalar},
            **{k: {"dtype": "int64", **scalar} for k in ("frame_index", "episode_index", "index", "task_index")}}


def write_source(demos: Path, root: Path) -> Path:
    """The LeRobot folder ``root`` of the ACT episodes in ``demos`` (module docstring)."""
    episodes = [read_episode(p) for p in episode_paths(demos)]
    tables, rows, videos, start = [], [], {VIDEO: []} | {image_key(c, LEROBOT): [] for c in CAMERAS}, 0
    for e, ep in enumerate(episodes):
        L = len(ep.qpos)
        frames = np.arange(L)
        tables.append(pa.table({
            LEROBOT_STATE: pa.array(list(ep.qpos), pa.list_(pa.float32(), 5)),
            "action": pa.array(list(ep.action), pa.list_(pa.float32(), 5)),
            IMAGE: pa.array([{"bytes": png_bytes(img), "path": f"frame-{t:06d}.png"}
                             for t, img in enumerate(ep.tactile["left"])]),
            FORCES[IMAGE]: pa.array(list(ep.force["left"]), pa.list_(pa.float32(), 3)),
            FORCES[VIDEO]: pa.array(list(ep.force["right"]), pa.list_(pa.float32(), 3)),
            "timestamp": pa.array(frames / FPS, pa.float32()), "frame_index": pa.array(frames),
            "episode_index": pa.array(np.full(L, e)), "index": pa.array(start + frames),
            "task_index": pa.array(np.zeros(L, np.int64))}))
        videos[VIDEO].append(ep.tactile["right"])
        for c in CAMERAS:
            videos[image_key(c, LEROBOT)].append(ep.images[c])
        row = {"episode_index": e, "tasks": ["grasp"], "length": L, "data/chunk_index": 0, "data/file_index": 0,
               "dataset_from_index": start, "dataset_to_index": start + L}
        for key in videos:
            row.update({f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                        f"videos/{key}/from_timestamp": start / FPS, f"videos/{key}/to_timestamp": (start + L) / FPS})
        row["stats"] = _episode_stats(tables[-1], ep)
        rows.append(row)
        start += L
    write_data_parquet(root / "data" / "chunk-000" / "file-000.parquet", pa.concat_tables(tables))
    for key, parts in videos.items():
        encode_video(root / "videos" / key / "chunk-000" / "file-000.mp4", np.concatenate(parts), FPS, "av1")
    _write_meta(root, rows, episodes[0], start)
    return root


def _episode_stats(table: pa.Table, ep) -> dict:
    """Per-episode stats of every feature (cameras at the frames LeRobot samples), as the recorder writes them."""
    picks = sample_indices(len(ep.qpos))
    images = {IMAGE: ep.tactile["left"], VIDEO: ep.tactile["right"],
              **{image_key(c, LEROBOT): ep.images[c] for c in CAMERAS}}
    stats = {key: image_stats(np.asarray(frames)[picks]) for key, frames in images.items()}
    for key in table.column_names:
        if key not in images:
            stats[key] = vector_stats(numbers(table.column(key)), key)
    return stats


def _write_meta(root: Path, rows: list[dict], ep, total: int) -> None:
    info = {"codebase_version": "v3.0", "robot_type": None, "total_episodes": len(rows), "total_frames": total,
            "total_tasks": 1, "chunks_size": 1000, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
            "fps": FPS, "splits": {"train": f"0:{len(rows)}"},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
            "features": _features(ep.tactile["left"].shape[1:], ep.images[CAMERAS[0]].shape[1:])}
    write_meta(root, info, rows, aggregate_stats([row["stats"] for row in rows]))
    pandas = {"index_columns": ["__index_level_0__"], "column_indexes": [], "columns": [
        {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
         "metadata": None},
        {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object",
         "metadata": None}]}
    tasks = pa.table({"task_index": pa.array([0]), "__index_level_0__": pa.array(["grasp"])})
    write_parquet(root / "meta" / "tasks.parquet", tasks.replace_schema_metadata({"pandas": json.dumps(pandas)}))
