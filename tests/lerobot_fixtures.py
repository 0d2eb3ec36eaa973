"""A LeRobot v3.0 source folder for the LeRobot write tests, written with pyarrow + PyAV (independently of the
writer under test): 2 episodes of 6 and 5 frames at 10 fps in one data file and one video file (episode 1 from
0.6 s); tactile cameras ``gelsight_left`` (image, PNG) and ``gelsight_right`` (video, H.264), each with a force
feature; a wrist video. Its info.json carries a key LeRobot main's DatasetInfo does not know (``total_videos``, a
v2.x leftover), lacks the file size settings, and its video features have ``info`` dicts (0.4.4's spelling for the
wrist, main's for the tactile one). ``augment``: ForceAugment over it with a tiny randomly initialised generator
(aug_fixtures)."""

import json
from fractions import Fraction
from functools import partial
from pathlib import Path

import av
import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aug_fixtures import tiny_generator
from controltac_il.augment import ForceAugment
from controltac_il.augment.provenance import chunk_done
from controltac_il.lerobot import LeRobotFolder, publish, staging_dir

FPS, LENGTHS, CONTACT = 10, (6, 5), ((1, 2, 3, 4), (2, 3))
LEFT, RIGHT, WRIST = "observation.images.gelsight_left", "observation.images.gelsight_right", "observation.images.wrist"
FORCES = {LEFT: "observation.gelsight_left.force", RIGHT: "observation.gelsight_right.force"}
H = W = 32
write_lerobot = partial(publish.write_lerobot, chunk_done=chunk_done)  # the cache's test, as the augment CLI wires it


def tactile(g: int, right: bool) -> np.ndarray:
    """uint8 (H, W, 3) tactile frame of global frame ``g``: flat gel, a pressed square while in contact."""
    e, t = (0, g) if g < LENGTHS[0] else (1, g - LENGTHS[0])
    img = np.full((H, W, 3), (110, 120, 100) if right else (100, 110, 120), np.int16)
    img += np.random.default_rng([g, right]).integers(-1, 2, (H, W, 3))
    if t in CONTACT[e]:
        img[8:24, 8:24] += 40 + 5 * t
    return img.clip(0, 255).astype(np.uint8)


def force(g: int) -> list[float]:
    return [0.2, -0.1, 2.0 + 0.5 * (g % 4)]


def _png(rgb):
    return cv2.imencode(".png", rgb[..., ::-1])[1].tobytes()


def _video(path, frames):
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=FPS)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt, stream.options = "yuv420p", {"crf": "0", "g": "2"}
        for k, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts, frame.time_base = k, Fraction(1, FPS)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())


def write_source(root, version="v3.0"):
    """The source folder (module docstring) in ``root``."""
    n = sum(LENGTHS)
    eps = np.repeat([0, 1], LENGTHS)
    frames = np.concatenate([np.arange(L) for L in LENGTHS])
    data = {"observation.state": pa.array([[g, -g, 0.5 * g] for g in range(n)], pa.list_(pa.float32(), 3)),
            "action": pa.array([[0.1 * g, 1.0] for g in range(n)], pa.list_(pa.float32(), 2)),
            LEFT: pa.array([{"bytes": _png(tactile(g, False)), "path": f"frame-{g:06d}.png"} for g in range(n)]),
            FORCES[LEFT]: pa.array([force(g) for g in range(n)], pa.list_(pa.float32(), 3)),
            FORCES[RIGHT]: pa.array([force(g + 1) for g in range(n)], pa.list_(pa.float32(), 3)),
            "timestamp": pa.array(frames / FPS, pa.float32()), "frame_index": pa.array(frames),
            "episode_index": pa.array(eps), "index": pa.array(np.arange(n)), "task_index": pa.array(eps)}
    (root / "data" / "chunk-000").mkdir(parents=True)
    table = pa.table(data)
    with pq.ParquetWriter(root / "data" / "chunk-000" / "file-000.parquet", table.schema) as w:
        w.write_table(table.slice(0, LENGTHS[0]))
        w.write_table(table.slice(LENGTHS[0]))
    wrist = [np.full((16, 24, 3), (10 * g, 200 - 10 * g, 90), np.uint8) for g in range(n)]
    _video(root / "videos" / WRIST / "chunk-000" / "file-000.mp4", wrist)
    _video(root / "videos" / RIGHT / "chunk-000" / "file-000.mp4", [tactile(g, True) for g in range(n)])
    rows = []
    for e, L in enumerate(LENGTHS):
        a = sum(LENGTHS[:e])
        row = {"episode_index": e, "tasks": [f"task {e}"], "length": L, "data/chunk_index": 0, "data/file_index": 0,
               "dataset_from_index": a, "dataset_to_index": a + L}
        for key in (WRIST, RIGHT):
            row.update({f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                        f"videos/{key}/from_timestamp": a / FPS, f"videos/{key}/to_timestamp": (a + L) / FPS})
        rows.append(row)
    (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    pq.write_table(pa.table({"task_index": [0, 1], "task": ["task 0", "task 1"]}), root / "meta" / "tasks.parquet")
    camera = {"shape": [H, W, 3], "names": ["height", "width", "channels"]}
    scalar = {"shape": [1], "names": None}
    video = {"video.codec": "h264", "video.pix_fmt": "yuv420p", "video.fps": FPS, "video.channels": 3,
             "has_audio": False}
    features = {"observation.state": {"dtype": "float32", "shape": [3], "names": ["x", "y", "z"]},
                "action": {"dtype": "float32", "shape": [2], "names": None},
                LEFT: {"dtype": "image", **camera},
                RIGHT: {"dtype": "video", **camera, "info": {"video.height": H, "video.width": W, **video,
                                                             "video.g": 2, "video.crf": 0, "is_depth_map": False}},
                WRIST: {"dtype": "video", "shape": [16, 24, 3], "names": ["height", "width", "channels"],
                        "info": {"video.height": 16, "video.width": 24, **video, "video.is_depth_map": False}},
                **{f: {"dtype": "float32", "shape": [3], "names": None} for f in FORCES.values()},
                "timestamp": {"dtype": "float32", **scalar},
                **{k: {"dtype": "int64", **scalar} for k in ("frame_index", "episode_index", "index", "task_index")}}
    info = {"codebase_version": version, "robot_type": None, "total_episodes": 2, "total_frames": n, "total_tasks": 2,
            "total_videos": 4, "chunks_size": 1000, "fps": FPS, "splits": {"train": "0:2"},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4", "features": features}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    return root


def augment(root, out, copies=2, generator=None):
    return ForceAugment(LeRobotFolder(root), generator or tiny_generator(), tactile_keys=[LEFT, RIGHT],
                        force_keys=FORCES, copies=copies, steps=1, cache_dir=staging_dir(out) / "cache",
                        build="manual", progress=False)


def write_clean(tmp: Path):
    """The ``written`` fixture (conftest: one per session): the source, one clean write of it, its counts and a
    ForceAugment cache of its own over the same source."""
    root, out = write_source(tmp / "source"), tmp / "out"
    aug = augment(root, out)
    counts = write_lerobot(aug, LeRobotFolder(root), out, progress=False)
    reference = ForceAugment(LeRobotFolder(root), aug.generator, tactile_keys=[LEFT, RIGHT], force_keys=FORCES,
                             copies=2, steps=1, cache_dir=tmp / "reference", progress=False)  # a cache of its own
    return root, out, counts, reference
