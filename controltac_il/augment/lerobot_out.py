"""An augmented LeRobot v3.0 folder from a built ForceAugment cache over a ``LeRobotFolder``.

Episodes: the source's, unchanged, first (output episode i is the source's i-th); then copy k of each, as
episode ``k * E + i`` (E source episodes), with ``episode_index`` and ``index`` renumbered and every other
column (``frame_index``, ``timestamp``, ``task_index``, actions, states, other cameras) copied. Copies'
tactile frames in contact are the cache's regenerated images: PNG bytes for image features; for video
features the episode is re-encoded with PyAV in the source's codec (``lerobot_v3_write.ENCODERS``) and the
round trip (squared error of the decoded regenerated frames, uint8 units) is measured per write.

Files: one data parquet per output episode (``chunk-{e // chunks_size}/file-{e % chunks_size}``); the source's
mp4 files copied under their own paths, referenced by the originals and by copies for every stream not
re-encoded; re-encoded streams one mp4 per output episode, numbered after the source's files. Per-frame
provenance features (``PREFIX``): ``augment.copy`` (0 = real), ``augment.offset`` and ``augment.jitter`` (N),
and per tactile camera ``augment.<camera>.status`` (STATUS code) and ``augment.<camera>.target_force``
(3,) N (the force the image shows: the target where regenerated, else the frame's label or reference force,
else 0). Names carry the camera's last name part, never "image" (LeRobot gives any feature named
"image..." camera-shaped stats).

Each output episode is written (data, videos) and then recorded by its meta row in ``done/`` (atomic): that
row marks it complete, so an interrupted write resumes where it stopped; ``finish`` writes ``meta/``.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow as pa
from tqdm import tqdm

from controltac_il.datasets.lerobot_v3 import decode_png, numbers
from controltac_il.datasets.lerobot_v3_write import (decode_video, encode_video, image_stats, png_bytes,
                                                     sample_indices, vector_stats, video_codec, write_data_parquet)
from controltac_il.io import atomic_path, write_json

PREFIX = "augment"
DEFAULTS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def provenance_names(tactile_keys) -> dict[str, str]:
    """tactile key -> the camera name of its provenance features; ValueError naming ``tactile_keys``."""
    names = {k: k.rsplit(".", 1)[-1] for k in tactile_keys}
    bad = [n for n in names.values() if "image" in n or list(names.values()).count(n) > 1]
    if bad:
        raise ValueError(f"tactile_keys: provenance features are named by each camera's last name part, which must "
                         f"be unique and free of 'image'; got {list(names.values())}")
    return names


def provenance_features(names: dict[str, str]) -> dict:
    """info.json features of the provenance columns."""
    scalar = {"shape": [1], "names": None}
    out = {f"{PREFIX}.copy": {"dtype": "int64", **scalar}, f"{PREFIX}.offset": {"dtype": "float32", **scalar},
           f"{PREFIX}.jitter": {"dtype": "float32", **scalar}}
    for n in names.values():
        out[f"{PREFIX}.{n}.status"] = {"dtype": "int64", **scalar}
        out[f"{PREFIX}.{n}.target_force"] = {"dtype": "float32", "shape": [3], "names": ["fx", "fy", "fz"]}
    return out


def check_tactile_features(features: dict, tactile_keys) -> None:
    """Each tactile key is an RGB image or video feature; ValueError naming ``tactile_keys``."""
    for k in tactile_keys:
        ft = features.get(k)
        if ft is None:
            raise ValueError(f"tactile_keys: {k!r} is not a feature of the dataset; its cameras are "
                             f"{[n for n, f in features.items() if f['dtype'] in ('image', 'video')]}")
        if ft["dtype"] not in ("image", "video") or tuple(ft["shape"])[-1:] != (3,):
            raise ValueError(f"tactile_keys: {k!r} is a {ft['dtype']} feature of shape {list(ft['shape'])}; a "
                             "tactile stream must be an RGB image or video feature (H, W, 3)")


class LeRobotExport:
    """Writes the augmented folder ``folder`` (module docstring) from ``aug`` (a ForceAugment in cache mode,
    its cache built) over ``source`` (the LeRobotFolder it wraps); ``done``: the per-episode meta rows."""

    def __init__(self, aug, source, folder: Path, done: Path):
        self.aug, self.source, self.folder, self.done = aug, source, Path(folder), Path(done)
        self.tactile = tuple(aug.tactile_keys)
        check_tactile_features(source.features, self.tactile)
        self.names = provenance_names(self.tactile)
        self.sources = sorted(source.episodes)
        self.copies = int(aug.config.copies)
        if self.copies < 1:
            raise ValueError("copies: an augmented LeRobot folder needs copies >= 1 (copy 0 is the source itself)")
        lengths = [int(source.episodes[e]["length"]) for e in self.sources] * (self.copies + 1)
        self.starts = np.concatenate([[0], np.cumsum(lengths)]).astype(int)
        self.chunks_size = int(source.meta.get("chunks_size", 1000))
        self.first_video = {k: self._first_free(k) for k in source.video_keys}

    @property
    def total(self) -> int:
        return len(self.sources) * (self.copies + 1)

    def _first_free(self, key: str) -> int:
        """The first file number (chunk * chunks_size + file) after every source file of video ``key``."""
        used = [int(ep[f"videos/{key}/chunk_index"]) * self.chunks_size + int(ep[f"videos/{key}/file_index"])
                for ep in self.source.episodes.values()]
        return max(used) + 1

    def _row_path(self, j: int) -> Path:
        return self.done / f"episode-{j:06d}.json"

    def missing(self) -> list[int]:
        """Source positions with an output episode not yet written."""
        E = len(self.sources)
        return [p for p in range(E) if any(not self._row_path(k * E + p).is_file() for k in range(self.copies + 1))]

    def write(self, rank: int = 0, world_size: int = 1, progress: bool = True, stop_after: int | None = None) -> dict:
        """Write this rank's share of the missing episodes (source position p belongs to rank p * world // E).
        stop_after: stop after this many output episodes (to split a write). Returns counts of the run."""
        E = len(self.sources)
        mine = [p for p in self.missing() if p * world_size // E == rank]
        counts = {"episodes": 0, "regenerated": 0, "video_sse": 0.0, "video_values": 0}
        bar = tqdm(total=len(mine) * (self.copies + 1), desc=f"writing episodes (rank {rank})", unit="episode",
                   disable=not progress, file=sys.stderr)
        for p in mine:
            for _ in self._write_source(p, counts):
                bar.update(1)
                if stop_after is not None and counts["episodes"] >= stop_after:
                    bar.close()
                    return counts
        bar.close()
        return counts

    def _write_source(self, p: int, counts: dict):
        """Write every missing output episode of source position ``p``; yields after each."""
        e = self.sources[p]
        table = self.source.episode_table(e)
        frames = table.column("frame_index").to_numpy().astype(int)
        real = {k: self._real_frames(table, e, k) for k in self.tactile}
        shared = self._shared_stats(table, e)
        first = self.aug.chunk(e, 1)
        for k in range(self.copies + 1):
            j = k * len(self.sources) + p
            if self._row_path(j).is_file():
                continue
            images, prov = self._copy_frames(e, k, frames, real, table, first)
            row = self._write_episode(j, e, table, images, prov, shared, counts)
            write_json(self._row_path(j), row)
            counts["episodes"] += 1
            yield j

    def _real_frames(self, table: pa.Table, e: int, key: str) -> np.ndarray:
        """RGB uint8 (L, H, W, 3) of tactile ``key`` in source episode ``e``."""
        if self.source.features[key]["dtype"] == "video":
            return self.source.video_frames(key, e)
        column, path = table.column(key).combine_chunks().field("bytes"), self.source.data_file(e)
        return np.stack(_parallel(lambda i: decode_png(column[i].as_py(), key, f"{path} (episode {e}, frame {i})"),
                                  range(len(column))))

    def _shared_stats(self, table: pa.Table, e: int) -> dict:
        """Stats of the features every copy of episode ``e`` shares (all but the tactile keys, provenance,
        episode_index and index)."""
        out = {}
        picks = sample_indices(len(table))
        for key, ft in self.source.features.items():
            if key in self.tactile or key in ("episode_index", "index"):
                continue
            if ft["dtype"] == "video":
                out[key] = image_stats(self.source.video_frames(key, e)[picks])
            elif ft["dtype"] == "image":
                column, path = table.column(key).combine_chunks().field("bytes"), self.source.data_file(e)
                out[key] = image_stats(np.stack(_parallel(
                    lambda i: decode_png(column[int(i)].as_py(), key, f"{path} (episode {e}, frame {i})"), picks)))
            elif ft["dtype"] != "string":
                out[key] = vector_stats(numbers(table.column(key)), key)
        return out

    def _copy_frames(self, e: int, k: int, frames, real: dict, table: pa.Table, first) -> tuple[dict, dict]:
        """Tactile frames of copy ``k`` of episode ``e`` ({key: (RGB (L, H, W, 3), regenerated (L,) bool)})
        and its provenance columns."""
        L, K = len(frames), len(self.tactile)
        status = np.zeros((K, L), np.int64)
        force = np.zeros((K, L, 3), np.float32)
        offset, jitter = np.zeros(L, np.float32), np.zeros(L, np.float32)
        images = {key: (real[key], np.zeros(L, bool)) for key in self.tactile}
        for j, key in enumerate(self.tactile):
            label = self.aug.keys.labels[key]
            if label is not None:
                force[j] = numbers(table.column(label)).reshape(L, 3)
            for i, t in enumerate(frames):
                ref = first.frames[int(t)].keys[j].reference
                if ref is not None and label is None:
                    force[j, i] = ref
        if k:
            chunk = self.aug.chunk(e, k)
            for j, key in enumerate(self.tactile):
                rgb, regen = real[key].copy(), np.zeros(L, bool)
                for i, t in enumerate(frames):
                    outcome = chunk.frames[int(t)]
                    offset[i], jitter[i] = outcome.offset, outcome.jitter
                    o = outcome.keys[j]
                    status[j, i] = o.status
                    if o.row >= 0:
                        rgb[i], regen[i], force[j, i] = chunk.files[j].read(o.row), True, o.target
                images[key] = (rgb, regen)
        prov = {f"{PREFIX}.copy": np.full(L, k, np.int64), f"{PREFIX}.offset": offset, f"{PREFIX}.jitter": jitter}
        for j, key in enumerate(self.tactile):
            prov[f"{PREFIX}.{self.names[key]}.status"] = status[j]
            prov[f"{PREFIX}.{self.names[key]}.target_force"] = force[j]
        return images, prov

    def _write_episode(self, j: int, e: int, table: pa.Table, images: dict, prov: dict, shared: dict,
                       counts: dict) -> dict:
        """Data file and videos of output episode ``j`` (copy of source episode ``e``); returns its meta row."""
        L, start = len(table), int(self.starts[j])
        src = self.source.episodes[e]
        out = table
        for key, (rgb, regen) in images.items():
            if self.source.features[key]["dtype"] == "image" and regen.any():
                out = _replace_images(out, key, rgb, regen)
        out = _set(out, "episode_index", np.full(L, j, np.int64))
        out = _set(out, "index", np.arange(start, start + L, dtype=np.int64))
        for name, values in prov.items():
            out = out.append_column(name, _arrow(values))
        write_data_parquet(self.folder / self.source.meta["data_path"].format(
            chunk_index=j // self.chunks_size, file_index=j % self.chunks_size), out)
        writer = {"regenerated": 0, "video_sse": 0.0, "video_values": 0}
        row = {"episode_index": j, "tasks": list(src["tasks"]), "length": L,
               "data/chunk_index": j // self.chunks_size, "data/file_index": j % self.chunks_size,
               "dataset_from_index": start, "dataset_to_index": start + L}
        for key in self.source.video_keys:
            row.update(self._video(j, e, key, images.get(key), writer))
        stats = dict(shared)
        for key, (rgb, regen) in images.items():
            stats[key] = image_stats(rgb[sample_indices(L)])
            writer["regenerated"] += int(regen.sum())
        for name, value in writer.items():
            counts[name] += value
        for key in ("episode_index", "index", *prov):
            stats[key] = vector_stats(numbers(out.column(key)), key)
        row["stats"] = {key: stats[key] for key in self.features() if key in stats}
        return {**row, "writer": writer}

    def _video(self, j: int, e: int, key: str, tactile, counts: dict) -> dict:
        """meta/episodes video columns of output episode ``j``: the source's segment (copied into the folder),
        or a re-encoded file of regenerated tactile frames."""
        src = self.source.episodes[e]
        cols = {f"videos/{key}/{c}": src[f"videos/{key}/{c}"]
                for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")}
        if tactile is None or not tactile[1].any():
            path = self.source.video_path(key, e)
            dest = self.folder / path.relative_to(self.source.root)
            if not dest.is_file():
                with atomic_path(dest, ".mp4") as tmp:
                    shutil.copyfile(path, tmp)
            return cols
        rgb, regen = tactile
        number = self.first_video[key] + j - len(self.sources)
        chunk, file = number // self.chunks_size, number % self.chunks_size
        dest = self.folder / self.source.meta["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
        codec, pix_fmt = video_codec(self.source.video_path(key, e))
        encode_video(dest, rgb, self.source.fps, codec, pix_fmt)
        decoded = decode_video(dest)
        diff = decoded[regen].astype(np.int32) - rgb[regen]
        counts["video_sse"] += float(np.einsum("i,i->", diff.ravel(), diff.ravel(), dtype=np.int64))
        counts["video_values"] += diff.size
        return {f"videos/{key}/chunk_index": chunk, f"videos/{key}/file_index": file,
                f"videos/{key}/from_timestamp": 0.0, f"videos/{key}/to_timestamp": len(rgb) / self.source.fps}

    def features(self) -> dict:
        """info.json features of the output: the source's user features, the provenance, the defaults; the source's
        dicts verbatim (LeRobot merges only folders whose shared features are identical)."""
        src = {k: {**ft, "shape": list(ft["shape"])} for k, ft in self.source.features.items()}
        user = {k: ft for k, ft in src.items() if k not in DEFAULTS}
        return {**user, **provenance_features(self.names), **{k: src[k] for k in DEFAULTS if k in src}}

    def rows(self) -> list[dict]:
        """Every output episode's meta row, in order (all written), with its ``writer`` counts (regenerated
        frames, video round trip squared error and values)."""
        return [json.loads(self._row_path(j).read_text()) for j in range(self.total)]


def _parallel(fn, items) -> list:
    """``[fn(x) for x in items]`` on a thread per core (PNG and video codecs release the GIL; the generator is
    idle while the folder is written)."""
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        return list(pool.map(fn, items))


def _arrow(values: np.ndarray) -> pa.Array:
    """A column as LeRobot writes it: scalars plain, vectors fixed_size_list."""
    if values.ndim == 1:
        return pa.array(values)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])


def _set(table: pa.Table, name: str, values: np.ndarray) -> pa.Table:
    i = table.schema.get_field_index(name)
    return table.set_column(i, table.schema.field(i), pa.array(values, type=table.schema.field(i).type))


def _replace_images(table: pa.Table, key: str, rgb: np.ndarray, regen: np.ndarray) -> pa.Table:
    """Image column ``key`` with the PNG of every regenerated frame replaced (others' bytes kept)."""
    i = table.schema.get_field_index(key)
    cells = table.column(i).to_pylist()
    rows = np.flatnonzero(regen)
    for r, data in zip(rows, _parallel(png_bytes, [rgb[r] for r in rows])):
        cells[r] = {**cells[r], "bytes": data}
    return table.set_column(i, table.schema.field(i), pa.array(cells, type=table.schema.field(i).type))
