"""Writes the files of a LeRobot v3.0 folder, each atomically (facts: ``docs/lerobot_v3_format.md``).

Data parquet files (one row group per episode), PNG image bytes, ``meta/episodes``, ``meta/stats.json`` and
``meta/info.json`` (exactly the keys of LeRobot main's typed ``DatasetInfo``, which drops any other on a rewrite;
lerobot 0.4.4 reads the same keys). The stats they hold come from ``stats``, the mp4 files from ``video``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from controltac_il.io import atomic_path, write_json

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
