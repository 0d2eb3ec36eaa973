"""Reads a LeRobot v3.0 dataset folder without LeRobot (pyarrow for parquet, PyAV for mp4).

    from controltac_il.lerobot import LeRobotFolder
    dataset = LeRobotFolder("you/peg_in_hole", delta_timestamps={"observation.images.gelsight_left": [-0.1, 0.0]})

Items are what ``LeRobotDataset(repo_id, root=...)`` (lerobot 0.4.4) returns, key for key and in its order:
video keys first, then the data columns in ``meta/info.json`` order, the ``<key>_is_pad`` masks, ``task``::

    observation.images.<camera>   float32 (3, H, W) in [0, 1]   image (PNG in the parquet) or video (mp4) feature, RGB
    <vector feature>              float32 / int64 / bool (D,)  (any float column as float32, any integer as int64)
    timestamp                     float32 ()                   s from the episode's start
    frame_index, episode_index, index, task_index   int64 ()
    task                          str                          (``subtask`` too where the dataset has subtasks)

With ``delta_timestamps={key: [offsets s]}`` item ``key`` is a window (T, ...) of the frames at ``index +
round(offset * fps)``, positions outside the episode repeating its first or last frame, and ``<key>_is_pad``
bool (T,) marks them (a video key with one offset stays (3, H, W), as in LeRobot).

Memory: at open, the episode, frame and timestamp of every frame (20 bytes a frame) and the episode table
without its stats; the other columns are read per parquet row group (LeRobot writes one per
episode) into a per-process LRU bounded by ``cache_mb``, images kept as PNG bytes and decoded per item.
Videos: ``video`` (one open file per video key and file per process, forward decoding without
seeking). Nothing stays open across pickling or a fork: DataLoader workers open their own files. A file that
cannot be read (parquet, mp4, the PNG bytes of an image) is refused in one ValueError line naming it.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections import OrderedDict
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import torch
from torch.utils.data import Dataset

from controltac_il.arrays import as_index
from controltac_il.config import is_int, is_real
from controltac_il.lerobot.video import TOLERANCE_S, VideoFrames

INDEX_COLUMNS = ("episode_index", "frame_index", "index", "timestamp")  # held in memory, read at open
CACHE_MB = 256  # default bound on the decoded row groups kept per process, MB
VERSION = re.compile(r"v3(\.\d+)*")
UNIT = (torch.arange(256, dtype=torch.float32) / 255).numpy()  # uint8 -> [0, 1] exactly as torch divides
PNG_START, PNG_END = b"\x89PNG\r\n\x1a\n", b"IEND\xaeB`\x82"  # signature; IEND chunk type and CRC


@contextmanager
def readable_parquet(path: Path):
    """pyarrow's errors reading the parquet ``path`` as one ValueError line naming it."""
    try:
        yield
    except (OSError, pa.ArrowException) as exc:
        raise ValueError(f"root: {path} is not a readable parquet file ({' '.join(str(exc).split())})") from None


def read_info(root: Path) -> dict:
    """``meta/info.json`` of a v3.x folder (feature shapes as tuples, as LeRobot loads them), checked."""
    path = root / "meta" / "info.json"
    if not root.is_dir() or not path.is_file():
        raise ValueError(f"root: {root} is not a LeRobot dataset folder (no meta/info.json)")
    try:
        info = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"root: {path} is not readable JSON ({exc})") from None
    version = info.get("codebase_version") if isinstance(info, dict) else None
    if not isinstance(version, str) or not VERSION.fullmatch(version):
        raise ValueError(f"root: unsupported codebase_version {version!r} in {path}; this reader reads v3.x "
                         "(convert v2.1 with LeRobot's convert_dataset_v21_to_v30)")
    missing = [k for k in ("fps", "features", "data_path") if k not in info]
    if missing:
        raise ValueError(f"root: {path} lacks {missing}")
    _check_info(info, path)
    for ft in info["features"].values():
        ft["shape"] = tuple(ft["shape"])
    return info


def _check_info(info: dict, path: Path) -> None:
    """The fields of ``info.json`` the reader relies on, each refused in one line naming it: a positive ``fps``,
    path templates as strings, ``features`` of a dtype string and a shape of ints each, the index columns."""
    fps = info["fps"]
    if not (is_real(fps) and fps > 0):
        raise ValueError(f"root: {path}: fps must be a positive number of frames per second, got {fps!r}")
    for key in ("data_path", "video_path"):
        if info.get(key) is not None and not isinstance(info[key], str):
            raise ValueError(f"root: {path}: {key} must be a path template string, got {info[key]!r}")
    features = info["features"]
    if not isinstance(features, dict):
        raise ValueError(f"root: {path}: features must be an object of name -> feature, got {type(features).__name__}")
    for name, ft in features.items():
        shape = ft.get("shape") if isinstance(ft, dict) else None
        if (not isinstance(ft, dict) or not isinstance(ft.get("dtype"), str) or not isinstance(shape, (list, tuple))
                or not all(is_int(d) and d >= 0 for d in shape)):
            raise ValueError(f"root: {path}: features.{name} needs a dtype (a string) and a shape (a list of "
                             f"ints), got {str(ft)[:80]}")
    lacking = [k for k in INDEX_COLUMNS if k not in features]
    if lacking:
        raise ValueError(f"root: {path}: features lack {lacking}, which every LeRobot frame has")


def read_tasks(root: Path, name: str = "tasks") -> list[str]:
    """Strings of ``meta/<name>.parquet`` in row order (LeRobot takes row ``task_index`` / ``subtask_index``):
    a pandas frame indexed by the string, or a column named ``task`` / ``subtask``."""
    path = root / "meta" / f"{name}.parquet"
    if not path.is_file():
        raise ValueError(f"root: {root} has no meta/{name}.parquet")
    with readable_parquet(path):
        table = pq.read_table(path)
    pandas = json.loads((table.schema.metadata or {}).get(b"pandas", b"{}"))
    named = [c for c in pandas.get("index_columns", []) if isinstance(c, str)]
    column = name[:-1] if name[:-1] in table.column_names else (named[0] if named else None)
    if column is None:
        raise ValueError(f"root: {path} has no strings (a {name[:-1]!r} column or a pandas index of them)")
    return [str(t) for t in table.column(column).to_pylist()]


def read_episodes(root: Path) -> dict[int, dict]:
    """Rows of ``meta/episodes/*/*.parquet`` by episode_index, ``stats/`` columns left unread."""
    paths = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not paths:
        raise ValueError(f"root: {root} has no meta/episodes/*/*.parquet")
    episodes = {}
    for p in paths:
        with readable_parquet(p):
            names = [n for n in pq.read_schema(p).names if not n.startswith("stats/")]
            rows = pq.read_table(p, columns=names).to_pylist()
        for row in rows:
            episodes[int(row["episode_index"])] = row
    return episodes


def read_episode_stats(root: Path, keys) -> dict[int, dict]:
    """{episode_index: {feature: {stat: value}}}: the ``stats/<feature>/<stat>`` columns of ``meta/episodes`` for
    the features ``keys``, as stored (nested lists; a null cell left out)."""
    keys, out = set(keys), {}
    for p in sorted((root / "meta" / "episodes").glob("*/*.parquet")):
        with readable_parquet(p):
            names = [n for n in pq.read_schema(p).names
                     if n.startswith("stats/") and n[len("stats/"):].rsplit("/", 1)[0] in keys]
            rows = pq.read_table(p, columns=["episode_index", *names]).to_pylist()
        for row in rows:
            stats = out.setdefault(int(row.pop("episode_index")), {})
            for name, value in row.items():
                feature, stat = name[len("stats/"):].rsplit("/", 1)
                if value is not None:
                    stats.setdefault(feature, {})[stat] = value
    return out


def delta_indices(delta_timestamps, features: dict, fps: int, tolerance_s: float) -> dict[str, list[int]] | None:
    """LeRobot's frame offsets ``round(d * fps)`` of ``delta_timestamps`` {key: [d s]}, checked as LeRobot
    checks them: |d * fps - round(d * fps)| / fps <= tolerance_s."""
    if delta_timestamps is None:
        return None
    if not isinstance(delta_timestamps, dict):
        raise ValueError(f"delta_timestamps: expected {{key: [offsets s]}}, got {type(delta_timestamps).__name__}")
    out = {}
    for key, deltas in delta_timestamps.items():
        if key not in features:
            raise ValueError(f"delta_timestamps: unknown key {key!r}; the features are {list(features)}")
        finite = isinstance(deltas, (list, tuple)) and all(is_real(d) for d in deltas)
        if features[key]["dtype"] == "string" or not finite or len(deltas) == 0:
            raise ValueError(f"delta_timestamps: {key!r} needs a non-empty list of finite offsets (s) of a "
                             f"non-string feature, got {deltas!r}")
        bad = [d for d in deltas if abs(d * fps - round(d * fps)) / fps > tolerance_s]
        if bad:
            raise ValueError(f"delta_timestamps: offsets {bad} s of {key!r} are not multiples of 1/{fps} s "
                             f"within tolerance_s={tolerance_s}")
        out[key] = [round(d * fps) for d in deltas]
    return out


def numbers(column) -> np.ndarray:
    """A numeric column (scalars or (fixed-size) lists, chunked or not, extension types unwrapped) as NumPy (N, D),
    D = 1 for scalars, in the column's own dtype."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    if isinstance(arr.type, pa.ExtensionType):
        arr = arr.storage
    n = len(arr)
    while pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type) or pa.types.is_fixed_size_list(arr.type):
        arr = arr.flatten()
    return arr.to_numpy(zero_copy_only=False).reshape(n, -1)


def _column(array: pa.ChunkedArray, feature: dict):
    """A row group's column: PNG bytes (pa.BinaryArray) of an image, strings as a list, else NumPy (N, *shape)
    ((N,) for shape (1,))."""
    arr = array.combine_chunks()
    if isinstance(arr.type, pa.ExtensionType):
        arr = arr.storage
    if feature["dtype"] == "image":
        return pc.struct_field(arr, "bytes")
    if feature["dtype"] == "string":
        return arr.to_pylist()
    n, shape = len(arr), tuple(feature["shape"])
    values = numbers(arr)
    return values.reshape(n) if shape == (1,) else values.reshape(n, *shape)


def _nbytes(column) -> int:
    return column.nbytes if hasattr(column, "nbytes") else sum(len(s) for s in column)


class _RowGroups:
    """Per-process LRU of decoded row groups (every data column), bounded by ``budget`` bytes (the newest
    group is always kept)."""

    def __init__(self, paths: list[Path], features: dict, budget: int):
        self.paths, self.features, self.budget = paths, features, budget
        self._reset()

    def _reset(self) -> None:
        self._files, self._cache, self._bytes, self._pid = {}, OrderedDict(), 0, os.getpid()

    def get(self, file: int, group: int) -> dict:
        """{column: values} of row group ``group`` of data file ``file``."""
        if self._pid != os.getpid():
            self._reset()
        entry = self._cache.pop((file, group), None)
        if entry is None:
            with readable_parquet(self.paths[file]):
                if file not in self._files:
                    self._files[file] = pq.ParquetFile(self.paths[file])
                table = self._files[file].read_row_group(group)
            columns = {k: _column(table.column(k), self.features[k]) for k in table.column_names if k in self.features}
            entry = (columns, sum(_nbytes(c) for c in columns.values()))
            self._bytes += entry[1]
        self._cache[(file, group)] = entry
        while self._bytes > self.budget and len(self._cache) > 1:
            self._bytes -= self._cache.popitem(last=False)[1][1]
        return entry[0]

    def __getstate__(self):
        return {"paths": self.paths, "features": self.features, "budget": self.budget}

    def __setstate__(self, state):
        self.__init__(**state)


def decode_png(data: bytes, key: str, where: str = "the parquet") -> np.ndarray:
    """RGB uint8 (H, W, 3) of PNG bytes; ValueError naming ``key`` and ``where`` (a file) for bytes that are no
    whole PNG (checked before decoding: OpenCV would print a warning of its own for a truncated one)."""
    whole = data.startswith(PNG_START) and data.rfind(PNG_END) > 0
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if whole else None
    if image is None:
        raise ValueError(f"{key}: an image of {where} is not a readable PNG")
    return image[..., ::-1]


def _chw_float(images: np.ndarray) -> torch.Tensor:
    """uint8 (..., H, W, 3) -> float32 (..., 3, H, W) in [0, 1], the values of LeRobot's ``x / 255``."""
    return torch.from_numpy(UNIT[np.moveaxis(images, -1, -3)])


def _tensor(values: np.ndarray) -> torch.Tensor:
    """Numbers as LeRobot returns them: floats float32, integers int64, bools bool."""
    kind = np.asarray(values).dtype.kind
    dtype = np.float32 if kind == "f" else np.int64 if kind in "iu" else bool
    return torch.from_numpy(np.array(values, dtype=dtype))


def _index_data(root: Path, features: dict):
    """Data files (sorted, as LeRobot concatenates them), (file, row group) of every row group, the global row
    where each starts (G + 1,) and the INDEX_COLUMNS of every row, checked."""
    paths = sorted((root / "data").glob("*/*.parquet"))
    if not paths:
        raise ValueError(f"root: {root} has no data/*/*.parquet")
    wanted = [k for k, ft in features.items() if ft["dtype"] != "video"]
    groups, starts, parts = [], [0], {k: [] for k in INDEX_COLUMNS}
    for f, path in enumerate(paths):
        with readable_parquet(path):
            pf = pq.ParquetFile(path)
            missing = [k for k in (*INDEX_COLUMNS, *wanted) if k not in pf.schema_arrow.names]
            if missing:
                raise ValueError(f"root: {path} lacks the columns {missing} of meta/info.json's features")
            table = pf.read(columns=list(INDEX_COLUMNS))
        for g in range(pf.num_row_groups):
            groups.append((f, g))
            starts.append(starts[-1] + pf.metadata.row_group(g).num_rows)
        for k in INDEX_COLUMNS:
            parts[k].append(table.column(k).to_numpy())
    cols = {k: np.concatenate(v).astype(np.int64) for k, v in parts.items() if k != "timestamp"}
    cols["timestamp"] = np.concatenate(parts["timestamp"]).astype(features["timestamp"]["dtype"])
    if not np.array_equal(cols["index"], np.arange(len(cols["index"]))):
        raise ValueError(f"root: the data rows of {root} are not in 'index' order 0..N-1 (LeRobot reads rows by "
                         "position)")
    return paths, np.asarray(groups, np.int64).reshape(-1, 2), np.asarray(starts, np.int64), cols


def _item_keys(keys, features: dict) -> set[str]:
    if keys is None:
        return set(features)
    unknown = [k for k in keys if k not in features]
    if unknown:
        raise ValueError(f"keys: {unknown} are not features of the dataset ({list(features)})")
    always = {"timestamp", "frame_index", "episode_index", "index", "task_index", "subtask_index"}
    return set(keys) | (always & set(features))


class LeRobotFolder(Dataset):
    """Frames of a LeRobot v3.x folder as ``LeRobotDataset`` items (module docstring), without LeRobot.

    Args:
        root: the dataset folder (``meta/``, ``data/``, ``videos/``); never written to.
        delta_timestamps: {feature key: [offsets s]}: windows, as ``LeRobotDataset``'s; None: single frames.
        tolerance_s: LeRobot's tolerance, s, of the offsets against multiples of 1/fps and of video frame times.
        cache_mb: bound on the decoded parquet row groups kept per process, MB.
        keys: the features items hold (the index columns and ``task_index`` always); None: every feature.
        video_threads: decoder threads per video file (``VideoFrames``; keep 1 under DataLoader workers).

    Attributes: ``meta`` (meta/info.json), ``features`` (its features, shapes as tuples), ``fps`` (frames/s),
    ``tasks`` (task strings by task_index), ``episodes`` ({episode_index: that row of meta/episodes without its
    stats: ``length``, ``dataset_from_index``, ``dataset_to_index`` (rows [from, to)), ``tasks``,
    ``videos/<key>/...``}), ``subtasks`` (or None), ``delta_timestamps`` and ``delta_indices`` ({key: [frame
    offsets]} or None), ``video_keys``.
    """

    def __init__(self, root, delta_timestamps=None, tolerance_s: float = TOLERANCE_S, cache_mb: float = CACHE_MB,
                 keys=None, video_threads: int = 1):
        if not (is_real(cache_mb) and cache_mb > 0):
            raise ValueError(f"cache_mb: expected a positive number of MB, got {cache_mb!r}")
        self.root = Path(root)
        self.meta = read_info(self.root)
        self.fps = int(self.meta["fps"])
        self.features = self.meta["features"]
        self.video_keys = [k for k, ft in self.features.items() if ft["dtype"] == "video"]
        self.item_keys = _item_keys(keys, self.features)
        self.delta_timestamps = delta_timestamps
        self.delta_indices = delta_indices(delta_timestamps, self.features, self.fps, tolerance_s)
        self.tasks = read_tasks(self.root)
        has_subtasks = "subtask_index" in self.features and (self.root / "meta" / "subtasks.parquet").is_file()
        self.subtasks = read_tasks(self.root, "subtasks") if has_subtasks else None
        self.episodes = read_episodes(self.root)
        paths, self._groups, self._starts, cols = _index_data(self.root, self.features)
        self._episode, self._frame, self._timestamp = cols["episode_index"], cols["frame_index"], cols["timestamp"]
        self._check_episodes()
        self._rows = _RowGroups(paths, self.features, int(cache_mb * 2**20))
        windows = [len(d) for k, d in (self.delta_indices or {}).items() if k in self.video_keys]
        self._videos = VideoFrames(keep=max(windows, default=1) + 1, tolerance_s=tolerance_s, threads=video_threads)

    def _check_episodes(self) -> None:
        """Every episode of the data is in meta/episodes, spans its rows [from, to) and has its videos."""
        found, counts = np.unique(self._episode, return_counts=True)
        unknown = sorted(set(found.tolist()) - set(self.episodes))
        if unknown:
            raise ValueError(f"root: episodes {unknown[:5]} of data/ are missing from meta/episodes")
        count = dict(zip(found.tolist(), counts.tolist()))
        if self.video_keys and not self.meta.get("video_path"):
            raise ValueError(f"root: meta/info.json has video features {self.video_keys} but no video_path")
        for e, ep in self.episodes.items():
            a, b = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
            if not (0 <= a < b <= len(self) and count.get(e) == b - a and np.all(self._episode[a:b] == e)):
                raise ValueError(f"root: meta/episodes puts episode {e} at rows [{a}, {b}), which data/ does not "
                                 f"hold ({count.get(e, 0)} rows of it)")
        videos = {self._video_path(key, ep): (key, e) for e, ep in self.episodes.items() for key in self.video_keys}
        for path, (key, e) in videos.items():
            if not path.is_file():
                raise ValueError(f"root: {path} (video {key!r} of episode {e}) is missing")

    def __len__(self) -> int:
        return len(self._episode)

    def frame_table(self) -> tuple[np.ndarray, np.ndarray]:
        """(episode_index, frame_index) int64 (N,) of every item, without reading any."""
        return self._episode.copy(), self._frame.copy()

    def fingerprint(self) -> dict:
        """Digest of the folder's meta files and its data files' names and sizes (what ForceAugment's cache
        records of its dataset)."""
        digest = hashlib.sha256()
        for path in [self.root / "meta" / "info.json", *sorted((self.root / "meta").glob("episodes/*/*.parquet")),
                     self.root / "meta" / "tasks.parquet"]:
            digest.update(path.read_bytes())
        for path in self._rows.paths:
            digest.update(f"{path.relative_to(self.root)}:{path.stat().st_size};".encode())
        return {"lerobot_sha256": digest.hexdigest()[:16]}

    def data_file(self, episode: int) -> Path:
        """The data parquet holding (the first row of) ``episode``."""
        first = int(self.episodes[int(episode)]["dataset_from_index"])
        g = int(np.searchsorted(self._starts, first, side="right") - 1)
        return self._rows.paths[int(self._groups[g][0])]

    def episode_table(self, episode: int) -> pa.Table:
        """The data rows of ``episode`` as stored (every column, arrow types kept), in row order."""
        ep = self.episodes[int(episode)]
        a, b = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        first = int(np.searchsorted(self._starts, a, side="right") - 1)
        last = int(np.searchsorted(self._starts, b - 1, side="right") - 1)
        parts = []
        for g in range(first, last + 1):
            file, group = (int(x) for x in self._groups[g])
            with readable_parquet(self._rows.paths[file]):
                table = pq.ParquetFile(self._rows.paths[file]).read_row_group(group)
            lo, hi = max(a - int(self._starts[g]), 0), min(b, int(self._starts[g + 1])) - int(self._starts[g])
            parts.append(table.slice(lo, hi - lo))
        return pa.concat_tables(parts).combine_chunks()

    def video_frames(self, key: str, episode: int) -> np.ndarray:
        """RGB uint8 (L, H, W, 3): every frame of video ``key`` in ``episode``, at its data timestamps."""
        ep = self.episodes[int(episode)]
        a, b = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        start = float(ep[f"videos/{key}/from_timestamp"])
        return self._videos.frames(self._video_path(key, ep), [start + float(t) for t in self._timestamp[a:b]])

    def video_path(self, key: str, episode: int) -> Path:
        """The mp4 holding video ``key`` of ``episode``."""
        return self._video_path(key, self.episodes[int(episode)])

    def _video_path(self, key: str, ep: dict) -> Path:
        chunk, file = int(ep[f"videos/{key}/chunk_index"]), int(ep[f"videos/{key}/file_index"])
        return self.root / self.meta["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)

    def _window(self, i: int, ep: dict) -> tuple[dict, dict]:
        """Rows of every windowed key (clamped to the episode, as LeRobot) and their pad masks (T,) bool."""
        a, b = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        rows, pads = {}, {}
        for key, offsets in (self.delta_indices or {}).items():
            rows[key] = [min(max(i + d, a), b - 1) for d in offsets]
            pads[f"{key}_is_pad"] = torch.tensor([not a <= i + d < b for d in offsets], dtype=torch.bool)
        return rows, pads

    def _data(self, key: str, rows: list[int], window: bool):
        """Column ``key`` at ``rows``: (T, ...) for a window, else its one value."""
        values, groups = [], [int(np.searchsorted(self._starts, r, side="right") - 1) for r in rows]
        for r, g in zip(rows, groups):
            values.append(self._rows.get(*self._groups[g])[key][r - int(self._starts[g])])
        dtype = self.features[key]["dtype"]
        if dtype == "string":
            return values[0]
        if dtype == "image":
            where = [f"{self._rows.paths[self._groups[g][0]]} (index {r})" for g, r in zip(groups, rows)]
            out = _chw_float(np.stack([decode_png(v.as_py(), key, w) for v, w in zip(values, where)]))
        else:
            out = _tensor(np.stack(values))
        return out if window else out[0]

    def _video(self, key: str, ep: dict, rows: list[int]) -> torch.Tensor:
        """Frames of video ``key`` at the data timestamps of ``rows`` (one row: (3, H, W), as LeRobot squeezes)."""
        start = float(ep[f"videos/{key}/from_timestamp"])
        times = [start + float(self._timestamp[r]) for r in rows]
        frames = _chw_float(self._videos.frames(self._video_path(key, ep), times))
        return frames[0] if len(rows) == 1 else frames

    def __getitem__(self, index) -> dict:
        n, index = len(self), as_index(index, "LeRobotFolder")
        if not -n <= index < n:
            raise IndexError(f"index {index} out of range for {n} frames")
        i = index % n
        ep = self.episodes[int(self._episode[i])]
        rows, pads = self._window(i, ep)
        item = {key: self._video(key, ep, rows.get(key, [i])) for key in self.video_keys if key in self.item_keys}
        for key, ft in self.features.items():
            if ft["dtype"] != "video" and key in self.item_keys:
                item[key] = self._data(key, rows.get(key, [i]), key in rows)
        item.update(pads)
        item["task"] = self.tasks[int(item["task_index"])]
        if self.subtasks is not None:
            item["subtask"] = self.subtasks[int(item["subtask_index"])]
        return item
