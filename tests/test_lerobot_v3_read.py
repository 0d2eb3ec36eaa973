"""LeRobotFolder reads LeRobot v3.0 folders without LeRobot: items (keys in LeRobot's order, dtypes, shapes,
values), windows padded with the episode's edge frames, video frames across files with few seeks, the frame
table ForceAugment reads, pickling, and one-line errors naming the argument.

The folders are written here by a minimal v3.0 writer (pyarrow + PyAV): 3 episodes of 5, 4 and 6 frames at
10 fps; episodes 0-1 in data file-000 and video file-000 (one stream, episode 1 from 0.5 s), episode 2 in
file-001 of each; two tactile image features (PNG in the parquet), one video feature, a force feature."""

import gc
import json
import os
import pickle
import shutil
import signal
import warnings
from fractions import Fraction

import av
import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from controltac_il.augment.items import index_columns
from controltac_il.datasets.stage import FrameTable
from controltac_il.lerobot import FrameTimestampError, LeRobotFolder
from aug_fixtures import tiny_generator

FPS = 10
LENGTHS = (5, 4, 6)
FILES = (0, 0, 1)  # data and video file of each episode
LEFT, RIGHT = "observation.images.gelsight_left", "observation.images.gelsight_right"
VIDEO, FORCE = "observation.images.wrist", "observation.gelsight_left.force"
H, W, VH, VW = 12, 16, 32, 48
TASKS = ("press the sensor", "slide the sensor")
VIDEO_TOL = 6 / 255  # lossless x264 in yuv420p: RGB -> YUV -> RGB rounding only


def tactile(key: str, g: int) -> np.ndarray:
    """uint8 (H, W, 3) of tactile ``key`` at global frame ``g`` (random: PNG must round-trip exactly)."""
    return np.random.default_rng([g, key == RIGHT]).integers(0, 256, (H, W, 3), dtype=np.uint8)


def video_colour(g: int) -> np.ndarray:
    """RGB of the flat video frame at global frame ``g``: 16 grey levels apart from any other frame's."""
    return np.array([8 + 16 * g, 247 - 16 * g, 128], np.uint8)


def vector(g: int, n: int, scale: float) -> list[float]:
    return [scale * (g + k / 3) for k in range(n)]


def _features() -> dict:
    image = {"dtype": "image", "shape": [H, W, 3], "names": ["height", "width", "channels"]}
    scalar = {"shape": [1], "names": None}
    return {
        "observation.state": {"dtype": "float32", "shape": [4], "names": None},
        "action": {"dtype": "float32", "shape": [4], "names": None},
        LEFT: image,
        VIDEO: {"dtype": "video", "shape": [VH, VW, 3], "names": ["height", "width", "channels"]},
        RIGHT: image,
        FORCE: {"dtype": "float32", "shape": [3], "names": None},
        "timestamp": {"dtype": "float32", **scalar},
        **{k: {"dtype": "int64", **scalar} for k in ("frame_index", "episode_index", "index", "task_index")},
    }


def _png(rgb: np.ndarray) -> bytes:
    return cv2.imencode(".png", rgb[..., ::-1])[1].tobytes()


def _write_data(root, starts) -> None:
    """data/chunk-000/file-00F.parquet, one row group per episode (as LeRobot writes)."""
    writers = {}
    for e, (n, f) in enumerate(zip(LENGTHS, FILES)):
        g = np.arange(starts[e], starts[e] + n)
        columns = {
            "observation.state": pa.array([vector(i, 4, 1.0) for i in g], pa.list_(pa.float32(), 4)),
            "action": pa.array([vector(i, 4, -0.5) for i in g], pa.list_(pa.float32(), 4)),
            LEFT: pa.array([{"bytes": _png(tactile(LEFT, i)), "path": None} for i in g]),
            RIGHT: pa.array([{"bytes": _png(tactile(RIGHT, i)), "path": None} for i in g]),
            FORCE: pa.array([vector(i, 3, 0.1) for i in g], pa.list_(pa.float32(), 3)),
            "timestamp": pa.array(np.arange(n) / FPS, pa.float32()),
            "frame_index": pa.array(np.arange(n)),
            "episode_index": pa.array(np.full(n, e)),
            "index": pa.array(g),
            "task_index": pa.array(np.full(n, int(e == 2))),
        }
        table = pa.table(columns)
        if f not in writers:
            path = root / "data" / "chunk-000" / f"file-{f:03d}.parquet"
            path.parent.mkdir(parents=True, exist_ok=True)
            writers[f] = pq.ParquetWriter(path, table.schema)
        writers[f].write_table(table)
    for w in writers.values():
        w.close()


def _write_video(path, frames: list[np.ndarray]) -> None:
    """One continuous H.264 stream (lossless, a keyframe every 3 frames), pts = frame count at 1/FPS."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = VW, VH, "yuv420p"
        stream.options = {"crf": "0", "g": "3", "sc_threshold": "0"}  # no scene cuts: every frame differs
        for k, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts, frame.time_base = k, Fraction(1, FPS)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())


def _write_meta(root, starts, version: str, shift: float) -> None:
    starts_in_file = {0: 0, 1: 0, 2: 0}  # first frame of each episode inside its video file
    starts_in_file[1] = LENGTHS[0]
    rows = {"episode_index": [], "tasks": [], "length": [], "data/chunk_index": [], "data/file_index": [],
            "dataset_from_index": [], "dataset_to_index": [], f"videos/{VIDEO}/chunk_index": [],
            f"videos/{VIDEO}/file_index": [], f"videos/{VIDEO}/from_timestamp": [],
            f"videos/{VIDEO}/to_timestamp": [], "stats/observation.state/mean": []}
    for e, (n, f) in enumerate(zip(LENGTHS, FILES)):
        for k, v in (("episode_index", e), ("tasks", [TASKS[int(e == 2)]]), ("length", n), ("data/chunk_index", 0),
                     ("data/file_index", f), ("dataset_from_index", starts[e]), ("dataset_to_index", starts[e] + n),
                     (f"videos/{VIDEO}/chunk_index", 0), (f"videos/{VIDEO}/file_index", f),
                     (f"videos/{VIDEO}/from_timestamp", starts_in_file[e] / FPS + shift),
                     (f"videos/{VIDEO}/to_timestamp", (starts_in_file[e] + n) / FPS),
                     ("stats/observation.state/mean", [0.0] * 4)):
            rows[k].append(v)
    (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.table(rows), root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    column = {"metadata": None}
    pandas = {"index_columns": ["__index_level_0__"], "column_indexes": [], "columns": [
        {**column, "name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64"},
        {**column, "name": None, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object"}]}
    tasks = pa.table({"task_index": pa.array([0, 1]), "__index_level_0__": pa.array(TASKS)})
    pq.write_table(tasks.replace_schema_metadata({"pandas": json.dumps(pandas)}), root / "meta" / "tasks.parquet")
    info = {"codebase_version": version, "robot_type": None, "total_episodes": len(LENGTHS),
            "total_frames": sum(LENGTHS), "total_tasks": len(TASKS), "chunks_size": 1000, "fps": FPS,
            "splits": {"train": f"0:{len(LENGTHS)}"},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
            "features": _features()}
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=2))


def write_folder(root, version: str = "v3.0", shift: float = 0.0):
    """A minimal LeRobot v3.0 folder at ``root`` (see the module docstring); ``shift`` (s) moves every episode's
    from_timestamp off its video frames."""
    starts = np.concatenate([[0], np.cumsum(LENGTHS)[:-1]]).tolist()
    _write_data(root, starts)
    _write_meta(root, starts, version, shift)
    for f in sorted(set(FILES)):
        frames = [video_colour(g) for e, g0 in enumerate(starts) if FILES[e] == f for g in range(g0, g0 + LENGTHS[e])]
        _write_video(root / "videos" / VIDEO / "chunk-000" / f"file-{f:03d}.mp4",
                     [np.broadcast_to(c, (VH, VW, 3)).copy() for c in frames])
    return root


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_folder(tmp_path_factory.mktemp("lerobot_v3"))


def video_frame_of(image: torch.Tensor) -> int:
    """Global frame whose colour a decoded video frame (3, H, W) float shows, checked within VIDEO_TOL."""
    colour = image.mean(dim=(1, 2)).numpy()
    g = int(np.argmin([np.abs(colour - video_colour(k) / 255).max() for k in range(sum(LENGTHS))]))
    assert np.abs(image.numpy() - video_colour(g)[:, None, None] / 255).max() <= VIDEO_TOL
    return g


def as_float(rgb: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255


def test_items_follow_lerobot_conventions(folder):
    ds = LeRobotFolder(folder)
    assert len(ds) == sum(LENGTHS) and ds.fps == FPS and ds.delta_indices is None
    item = ds[6]  # episode 1, frame 1
    assert list(item) == [VIDEO, "observation.state", "action", LEFT, RIGHT, FORCE, "timestamp", "frame_index",
                          "episode_index", "index", "task_index", "task"]
    for key in (VIDEO, LEFT, RIGHT):
        assert item[key].dtype == torch.float32 and 0 <= float(item[key].min()) <= float(item[key].max()) <= 1
    assert item[VIDEO].shape == (3, VH, VW) and item[LEFT].shape == item[RIGHT].shape == (3, H, W)
    assert torch.equal(item[LEFT], as_float(tactile(LEFT, 6))) and torch.equal(item[RIGHT], as_float(tactile(RIGHT, 6)))
    assert video_frame_of(item[VIDEO]) == 6
    assert item["observation.state"].dtype == torch.float32 and item["observation.state"].shape == (4,)
    assert torch.equal(item[FORCE], torch.tensor(vector(6, 3, 0.1), dtype=torch.float32))
    assert item["timestamp"].shape == () and item["timestamp"].dtype == torch.float32
    assert abs(float(item["timestamp"]) - 0.1) < 1e-6
    for key, value in (("frame_index", 1), ("episode_index", 1), ("index", 6), ("task_index", 0)):
        assert item[key].dtype == torch.int64 and item[key].shape == () and int(item[key]) == value
    assert item["task"] == TASKS[0] and ds[-1]["task"] == TASKS[1]
    for bad, error, says in ((len(ds), IndexError, "out of range"), (1.7, TypeError, "^LeRobotFolder indices are ints")):
        with pytest.raises(error, match=says):
            ds[bad]


def test_windows_repeat_the_episode_edges_and_mark_them(folder):
    dt = {LEFT: [-0.2, -0.1, 0.0], VIDEO: [-0.1, 0.0, 0.1], "action": [0.0, 0.1, 0.2]}
    ds = LeRobotFolder(folder, delta_timestamps=dt)
    assert ds.delta_indices == {LEFT: [-2, -1, 0], VIDEO: [-1, 0, 1], "action": [0, 1, 2]}
    first = ds[5]  # episode 1 (rows 5..8), frame 0
    assert list(first)[-4:] == [f"{LEFT}_is_pad", f"{VIDEO}_is_pad", "action_is_pad", "task"]
    assert first[LEFT].shape == (3, 3, H, W) and first[VIDEO].shape == (3, 3, VH, VW)
    assert first[f"{LEFT}_is_pad"].tolist() == [True, True, False] and first[f"{LEFT}_is_pad"].dtype == torch.bool
    for p in range(3):
        assert torch.equal(first[LEFT][p], as_float(tactile(LEFT, 5)))
    assert [video_frame_of(f) for f in first[VIDEO]] == [5, 5, 6]
    assert first[f"{VIDEO}_is_pad"].tolist() == [True, False, False]
    last = ds[8]  # episode 1, frame 3 (its last)
    assert last["action_is_pad"].tolist() == [False, True, True] and last["action"].shape == (3, 4)
    assert torch.equal(last["action"], torch.tensor([vector(8, 4, -0.5)] * 3, dtype=torch.float32))
    assert [video_frame_of(f) for f in last[VIDEO]] == [7, 8, 8]
    assert last[LEFT].shape == (3, 3, H, W) and not last[f"{LEFT}_is_pad"].any()
    assert torch.equal(last[LEFT][0], as_float(tactile(LEFT, 6)))
    assert last["observation.state"].shape == (4,)  # keys without offsets stay single frames


def test_video_frames_across_files_in_any_order_with_few_seeks(folder):
    ds = LeRobotFolder(folder)
    assert [video_frame_of(ds[i][VIDEO]) for i in range(len(ds))] == list(range(len(ds)))
    assert ds._videos.seeks == 2  # one per file: sequential reading decodes forward
    backwards = LeRobotFolder(folder)
    assert [video_frame_of(backwards[i][VIDEO]) for i in reversed(range(len(ds)))] == list(reversed(range(len(ds))))


def test_row_group_cache_stays_within_its_bound(folder):
    small, default = LeRobotFolder(folder, cache_mb=1e-4), LeRobotFolder(folder)
    for i in (0, 9, 5, 14, 1):
        a, b = small[i], default[i]
        assert all(torch.equal(a[k], b[k]) for k in a if isinstance(a[k], torch.Tensor))
    assert len(small._rows._cache) == 1 and len(default._rows._cache) == len(LENGTHS)


def test_frame_table_and_metadata_for_force_augment(folder):
    ds = LeRobotFolder(folder)
    assert isinstance(ds, FrameTable)
    episodes, frames = ds.frame_table()
    assert episodes.dtype == frames.dtype == np.int64
    assert episodes.tolist() == [e for e, n in enumerate(LENGTHS) for _ in range(n)]
    assert frames.tolist() == [t for n in LENGTHS for t in range(n)]
    assert [index_columns(ds, len(ds))[k].tolist() for k in (0, 1)] == [episodes.tolist(), frames.tolist()]
    assert {e: (ep["length"], ep["dataset_from_index"], ep["dataset_to_index"]) for e, ep in ds.episodes.items()} \
        == {0: (5, 0, 5), 1: (4, 5, 9), 2: (6, 9, 15)}
    assert not any(k.startswith("stats/") for k in ds.episodes[0])
    assert ds.tasks == list(TASKS) and ds.meta["codebase_version"] == "v3.0"
    assert ds.features[LEFT]["shape"] == (H, W, 3) and ds.video_keys == [VIDEO]


def test_pickled_copies_and_workers_read_the_same_items(folder):
    ds = LeRobotFolder(folder, delta_timestamps={VIDEO: [-0.1, 0.0]})
    before = ds[3]
    copy = pickle.loads(pickle.dumps(ds))
    assert not ds._videos._streams and not copy._videos._streams  # files closed on pickling, none carried
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=4, num_workers=1)))
    for got in (copy[3], {k: v[3] for k, v in batch.items()}):
        assert got["task"] == before["task"]
        for key, value in before.items():
            if isinstance(value, torch.Tensor):
                assert torch.equal(got[key], value), key


def test_a_forked_worker_frees_the_parents_decoders_without_hanging(folder):
    """A DataLoader worker forked while the parent holds open decoders frees them (here on purpose): a threaded
    FFmpeg decoder deadlocks there, so the reader's decoders are single-threaded."""
    ds = LeRobotFolder(folder)
    ds[0], ds[len(ds) - 1]
    # only this reader's decoders are left for the child to free, not other tests' garbage (the augment command,
    # run in this process by other tests, decodes with FFmpeg's threads: as a command it never forks)
    gc.collect()
    pid = os.fork()
    if pid == 0:
        ds._videos._streams.clear()
        gc.collect()
        os._exit(0)

    def hung(*_):
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the forked child hung freeing the parent's video decoders")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(10)  # a hang is the failure: the wait is cut off, never polled
    try:
        _, status = os.waitpid(pid, 0)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert os.waitstatus_to_exitcode(status) == 0, "the forked child failed freeing the parent's video decoders"


def test_bad_inputs_are_refused_in_one_line_naming_the_argument(folder, tmp_path):
    cases = [
        (tmp_path / "missing", None, r"^root: .* is not a LeRobot dataset folder"),
        (tmp_path, None, r"^root: .* is not a LeRobot dataset folder \(no meta/info.json\)"),
        (folder, {"observation.nope": [0.0]}, r"^delta_timestamps: unknown key 'observation.nope'"),
        (folder, {LEFT: [-0.1, 0.05]}, r"^delta_timestamps: offsets \[0.05\] s of .* not multiples of 1/10 s"),
        (folder, {LEFT: 0.1}, r"^delta_timestamps: .* needs a non-empty list of finite offsets \(s\)"),
        (folder, {LEFT: [float("nan")]}, r"^delta_timestamps: .* needs a non-empty list of finite offsets \(s\)"),
    ]
    old = write_folder(tmp_path / "old", version="v2.1")
    cases.append((old, None, r"^root: unsupported codebase_version 'v2.1'"))
    for root, dt, message in cases:
        with pytest.raises(ValueError, match=message) as err:
            LeRobotFolder(root, delta_timestamps=dt)
        assert "\n" not in str(err.value)
    shifted = LeRobotFolder(write_folder(tmp_path / "shifted", shift=0.5 / FPS))  # half a frame off
    with pytest.raises(FrameTimestampError, match=r"no frame within 0.0001 s of 0.050000 s") as err:
        shifted[0]
    assert "\n" not in str(err.value) and isinstance(err.value, ValueError)
    LeRobotFolder(folder, delta_timestamps={LEFT: [-0.1 + 1e-5]})  # within LeRobot's tolerance_s (1e-4 s)


@pytest.mark.parametrize("edit, says", [
    (lambda i: i["features"]["action"].pop("shape"), r"features.action needs a dtype \(a string\) and a shape"),
    (lambda i: i.update(features=[1, 2]), "features must be an object of name -> feature, got list"),
    (lambda i: i.update(fps=0), "fps must be a positive number of frames per second, got 0"),
    (lambda i: i.update(fps="30"), "fps must be a positive number of frames per second, got '30'"),
    (lambda i: i["features"].pop("timestamp"), r"features lack \['timestamp'\], which every LeRobot frame has"),
    (lambda i: i.update(video_path=7), "video_path must be a path template string, got 7"),
])
def test_an_info_json_the_reader_cannot_rely_on_is_refused_naming_its_field(folder, tmp_path, edit, says):
    from controltac_il.lerobot import LeRobotEpisodes

    root = tmp_path / "edited"
    shutil.copytree(folder, root)
    info = json.loads((root / "meta" / "info.json").read_text())
    edit(info)
    (root / "meta" / "info.json").write_text(json.dumps(info))
    for call in (lambda: LeRobotFolder(root), lambda: LeRobotEpisodes(root, chunk_size=2, tactile_keys=[LEFT])):
        with pytest.raises(ValueError, match=rf"^root: {root / 'meta' / 'info.json'}: {says}") as err:
            call()
        assert "\n" not in str(err.value)


def _one_line_naming(path, call) -> str:
    """The ValueError ``call()`` raises: one line naming ``path``."""
    with pytest.raises(ValueError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message and str(path) in message, message
    return message


def test_unreadable_files_are_refused_in_one_line_naming_them(folder, tmp_path):
    def truncated(name: str, rel: str):
        root = tmp_path / name
        shutil.copytree(folder, root)
        path = root / rel
        path.write_bytes(path.read_bytes()[:path.stat().st_size // 2])
        return root, path

    parquets = {"data": "data/chunk-000/file-001.parquet", "episodes": "meta/episodes/chunk-000/file-000.parquet",
                "tasks": "meta/tasks.parquet"}
    for name, rel in parquets.items():
        root, path = truncated(name, rel)
        message = _one_line_naming(path, lambda: LeRobotFolder(root))
        assert message.startswith(f"root: {path} is not a readable parquet file (") and "magic bytes" in message
    root, path = truncated("mp4", f"videos/{VIDEO}/chunk-000/file-001.mp4")
    ds = LeRobotFolder(root)
    assert video_frame_of(ds[0][VIDEO]) == 0  # file-000 is whole
    message = _one_line_naming(path, lambda: ds[len(ds) - 1])
    assert message.startswith(f"{path} is not a readable video file ("), message
    root = tmp_path / "png"
    shutil.copytree(folder, root)
    path = root / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(path)
    cells = table.column(LEFT).to_pylist()
    cells[2]["bytes"], cells[3]["bytes"] = cells[2]["bytes"][:-20], b"not a PNG"  # truncated; not a PNG at all
    i = table.schema.get_field_index(LEFT)
    pq.write_table(table.set_column(i, table.schema.field(i), pa.array(cells, table.schema.field(i).type)), path)
    ds = LeRobotFolder(root)
    assert torch.equal(ds[1][LEFT], as_float(tactile(LEFT, 1)))
    for index in (2, 3):
        message = _one_line_naming(path, lambda: ds[index])
        assert message == f"{LEFT}: an image of {path} (index {index}) is not a readable PNG", message


def test_a_corrupt_tactile_png_read_through_lerobot_episodes_is_refused_naming_its_file(folder, tmp_path):
    from controltac_il.lerobot import LeRobotEpisodes

    root = (tmp_path / "episodes_png").resolve()  # LeRobotEpisodes names the resolved path
    shutil.copytree(folder, root)
    path = root / "data" / "chunk-000" / "file-000.parquet"  # episodes 0 (frames 0-4) and 1
    table = pq.read_table(path)
    cells = table.column(LEFT).to_pylist()
    cells[7]["bytes"] = cells[7]["bytes"][:-20]  # episode 1, frame 2: truncated
    i = table.schema.get_field_index(LEFT)
    pq.write_table(table.set_column(i, table.schema.field(i), pa.array(cells, table.schema.field(i).type)), path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # backgrounds estimated per episode
        message = _one_line_naming(path, lambda: LeRobotEpisodes(root, chunk_size=2, tactile_keys=[LEFT]))
    assert message == f"{LEFT}: an image of {path} (episode 1, frame 2) is not a readable PNG", message


def _edited_column(folder, root, key, edit):
    """A copy of ``folder`` at ``root`` whose column ``key`` in file-000 (episodes 0 and 1) is ``edit(rows)``."""
    shutil.copytree(folder, root)
    path = root / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(path)
    i = table.schema.get_field_index(key)
    rows = edit(table.column(key).to_pylist())
    pq.write_table(table.set_column(i, table.schema.field(i), pa.array(rows, table.schema.field(i).type)), path)


@pytest.mark.parametrize("key", ["observation.state", "action", FORCE])
def test_a_nan_in_the_state_the_actions_or_a_force_label_is_refused_naming_episode_and_frame(folder, tmp_path, key):
    from controltac_il.lerobot import LeRobotEpisodes

    def nan_at_episode_1_frame_2(rows):
        rows[7][-1] = float("nan")
        return rows

    _edited_column(folder, tmp_path / "nan", key, nan_at_episode_1_frame_2)
    with pytest.raises(ValueError, match=rf"^nan: {key} holds NaN or inf \(first at episode 1, frame 2\); it must be finite$"):
        LeRobotEpisodes(tmp_path / "nan", chunk_size=2, tactile_keys=[LEFT])


def test_a_constant_action_dimension_gets_the_std_floor_as_an_hdf5_folder_does(folder, tmp_path):
    """An action component that never moves (a gripper held shut): normalising by its std of 0 would divide by 0."""
    from controltac_il.datasets.act_dataset import STD_FLOOR
    from controltac_il.lerobot import LeRobotEpisodes

    root = tmp_path / "const"
    shutil.copytree(folder, root)
    for path in (root / "data").rglob("*.parquet"):
        table = pq.read_table(path)
        i = table.schema.get_field_index("action")
        rows = [[r[0], 1.0, *r[2:]] for r in table.column("action").to_pylist()]
        pq.write_table(table.set_column(i, table.schema.field(i), pa.array(rows, table.schema.field(i).type)), path)
    stats = LeRobotEpisodes(root, chunk_size=2, tactile_keys=[LEFT]).stats
    assert stats["action"]["std"][1] == np.float32(STD_FLOOR) and (np.delete(stats["action"]["std"], 1) > STD_FLOOR).all()
    assert stats["action"]["mean"][1] == 1.0


def test_a_tactile_sensor_the_dataset_lacks_is_refused_never_an_empty_selection(folder):
    from controltac_il.lerobot import LeRobotEpisodes

    with pytest.raises(ValueError, match=r"^force_keys: expected \{tactile key: force key\}, got list$"):
        LeRobotEpisodes(folder, chunk_size=2, tactile_keys=[LEFT], force_keys=[FORCE])
    with pytest.raises(ValueError, match=r"^tactile_sensors: \['gelsight_nope'\] are not tactile cameras of the dataset"):
        LeRobotEpisodes(folder, chunk_size=2, tactile_keys=[LEFT], tactile_sensors=["gelsight_nope"])
    assert LeRobotEpisodes(folder, chunk_size=2, tactile_keys=[LEFT], tactile_sensors=()).tactile_sensors == []


def test_force_labels_in_mn_or_pulling_are_refused_as_an_hdf5_episodes_are(folder, tmp_path):
    from controltac_il.lerobot import LeRobotEpisodes

    _edited_column(folder, tmp_path / "mn", FORCE, lambda rows: [[1000 * v for v in r] for r in rows])
    with pytest.raises(ValueError, match=rf"^mn: {FORCE} reaches .*are the labels in mN"):
        LeRobotEpisodes(tmp_path / "mn", chunk_size=2, tactile_keys=[LEFT])
    _edited_column(folder, tmp_path / "pull", FORCE, lambda rows: [[-v for v in r] for r in rows])
    with pytest.raises(ValueError, match="negative median Fz in contact"):
        LeRobotEpisodes(tmp_path / "pull", chunk_size=2, tactile_keys=[LEFT])


def test_a_force_feature_found_by_name_must_be_three_forces(folder, tmp_path):
    from controltac_il.lerobot import LeRobotEpisodes

    root = tmp_path / "fz_only"
    shutil.copytree(folder, root)
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"][FORCE]["shape"] = [1]  # e.g. a load cell's Fz alone
    (root / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(ValueError, match=rf"^force_keys: \['{FORCE} \(1,\)'\] are not \(3,\) \[Fx, Fy, Fz\] N features"):
        LeRobotEpisodes(root, chunk_size=2, tactile_keys=[LEFT])


def test_force_augment_wraps_a_folder_with_windows_and_labels(folder, tmp_path):
    from controltac_il.augment import ForceAugment

    ds = LeRobotFolder(folder, delta_timestamps={LEFT: [-0.1, 0.0]})
    aug = ForceAugment(ds, tiny_generator(), tactile_keys=[LEFT], force_keys={LEFT: FORCE}, copies=1, mode="online")
    assert len(aug) == 2 * len(ds)
    real, copy = aug[6], aug[len(ds) + 6]
    assert torch.equal(real[LEFT], ds[6][LEFT]) and copy[LEFT].shape == (2, 3, H, W)
    assert torch.equal(copy[VIDEO], ds[6][VIDEO]) and torch.equal(copy[f"{LEFT}_is_pad"], ds[6][f"{LEFT}_is_pad"])
    assert int(aug.info(copy)["copy"]) == 1


def test_cli_takes_a_lerobot_folder_and_its_force_keys(folder, tmp_path, capsys):
    from controltac_il.augment import main
    from controltac_il.generator.checkpoint import save_checkpoint

    g = tiny_generator()
    ckpt = save_checkpoint(tmp_path / "gen", g.config, g.autoencoder, g.denoiser)
    args = ["--dataset", str(folder), "--out", str(tmp_path / "augmented"), "--copies", "1", "--steps", "1",
            "--generator", str(ckpt), "--tactile-keys", LEFT, RIGHT]
    assert main([*args, "--force-keys", f"{LEFT}={FORCE}"]) == 0
    assert "6 episodes (3 original + 1 copies of each), 30 frames" in capsys.readouterr().out
    assert main([*args, "--force-keys", LEFT]) == 2
    assert "--force-keys: expected TACTILE_KEY=FORCE_KEY" in capsys.readouterr().err
    named = [*args[:2], "--out", str(tmp_path / "named"), *args[4:-2], "gelsight_left", "gelsight_right"]  # by name
    assert main([*named, "--force-keys", f"{LEFT}={FORCE}"]) == 0 and "30 frames" in capsys.readouterr().out
    bogus = [*args[:2], "--out", str(tmp_path / "bogus"), "--generator", str(ckpt), "--tactile-keys", "bogus"]
    assert main(bogus) == 2
    err = capsys.readouterr().err
    assert f"--tactile-keys: 'bogus' is not a camera of {folder}; its cameras are [" in err and LEFT in err, err
