"""Writes an augmented LeRobot v3.0 folder from a built ForceAugment cache over a ``LeRobotFolder``.

Episodes: the source's, unchanged, first (output episode i is the source's i-th); then copy k of each, as
episode ``k * E + i`` (E source episodes), with ``episode_index`` and ``index`` renumbered and every other
column (``frame_index``, ``timestamp``, ``task_index``, actions, states, other cameras) copied. Copies'
tactile frames in contact are the cache's regenerated images: PNG bytes for image features; for video
features the episode is re-encoded with PyAV in the source's codec (``video.ENCODERS``); with
``round_trip`` each re-encoded file is decoded back and the codec's round trip (squared error of the decoded
regenerated frames, uint8 units) measured (a decode of every re-encoded stream; off by default).

Files: one data parquet per output episode (``chunk-{e // chunks_size}/file-{e % chunks_size}``); the source's
mp4 files copied under their own paths, referenced by the originals and by copies for every stream not
re-encoded; re-encoded streams one mp4 per output episode, numbered after the source's files. Per-frame
provenance features (``PREFIX``): ``augment.copy`` (0 = real), ``augment.offset`` and ``augment.jitter`` (N),
and per tactile camera ``augment.<camera>.status`` (STATUS code) and ``augment.<camera>.target_force``
(3,) N (the force the image shows: the target where regenerated, else the frame's label or reference force,
else 0). Names carry the camera's last name part, never "image" (LeRobot gives any feature named
"image..." camera-shaped stats).

Stats (``stats``) are those of the frames written, and what output episodes share is computed once:
the features every copy holds unchanged (cameras, actions, states) once per source episode, or taken from the
source's own per-episode stats where its ``meta/episodes`` holds them complete (``lerobot-record`` writes them; the
stats of the very frames copied, so an unchanged camera is not decoded for them); a tactile camera's
from per-frame channel histograms, the source's at the sampled frames with the regenerated frames' in their place
(equal to recomputing them from the copy's frames: a frame's histogram depends on that frame alone). A tactile
image feature's PNGs are decoded only at the frames its stats sample (all of an episode shorter than 100 frames).

Each output episode is written (data, videos) and then recorded by its meta row in ``done/`` (atomic): that
row marks it complete, so an interrupted write resumes where it stopped; ``publish.finish`` writes ``meta/``.
With ``workers`` > 1, that many processes write them, each taking whole source episodes (the original and its
copies share its decoded frames) once all their chunks are built; the files are the same, byte for byte.
"""

from __future__ import annotations

import copy
import json
import multiprocessing
import os
import queue
import shutil
import signal
import sys
import threading
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from tqdm import tqdm

from controltac_il.cli import RunFault, tty_only
from controltac_il.io import atomic_path, write_json
from controltac_il.lerobot.provenance import COPY, PREFIX, provenance_features, provenance_names
from controltac_il.lerobot.reader import decode_png, numbers, read_episode_stats
from controltac_il.lerobot.stats import (STAT_NAMES, complete_stats, frame_histograms, histogram_stats, image_stats,
                                         sample_indices, vector_stats)
from controltac_il.lerobot.video import decode_video, encode_video, video_codec
from controltac_il.lerobot.writer import png_bytes, write_data_parquet

DEFAULTS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


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


@dataclass
class _Source:
    """What every output episode of source episode ``index`` reads: its data rows, the frames its stats sample
    (``picks``), every frame of its tactile videos (RGB (L, H, W, 3)), its tactile frames' channel histograms at
    ``picks`` (int64 (len(picks), 3, 256)) and the stats of the features its copies share."""

    index: int
    table: pa.Table
    picks: np.ndarray
    videos: dict
    histograms: dict
    shared: dict


class LeRobotExport:
    """Writes the augmented folder ``folder`` (module docstring) from ``aug`` (a ForceAugment in cache mode,
    its cache built) over ``source`` (the LeRobotFolder it wraps); ``done``: the per-episode meta rows;
    ``round_trip``: decode each re-encoded video back and count its squared error (module docstring);
    ``workers``: processes writing the output episodes (1: this one)."""

    def __init__(self, aug, source, folder: Path, done: Path, round_trip: bool = False, workers: int = 1):
        self.aug, self.source, self.folder, self.done = aug, source, Path(folder), Path(done)
        self.round_trip = bool(round_trip)
        if int(workers) < 1:
            raise ValueError(f"workers: expected an int >= 1 (processes writing output episodes), got {workers}")
        self.workers = int(workers)
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
        self.shared = [k for k, ft in source.features.items()
                       if k not in (*self.tactile, "episode_index", "index") and ft["dtype"] != "string"]
        self.given = read_episode_stats(source.root, self.shared)

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

    def _todo(self, p: int) -> list[int]:
        """The copies of source position ``p`` whose output episode is not written yet (0: the original)."""
        E = len(self.sources)
        return [k for k in range(self.copies + 1) if not self._row_path(k * E + p).is_file()]

    def missing(self) -> list[int]:
        """Source positions with an output episode not yet written."""
        return [p for p in range(len(self.sources)) if self._todo(p)]

    def write(self, rank: int = 0, world_size: int = 1, progress: bool = True, stop_after: int | None = None,
              ready=None) -> dict:
        """Write this rank's share of the missing episodes (source position p belongs to rank p * world // E).
        stop_after: stop after this many output episodes (to split a write; with workers, after the source
        position that reaches it). ready: called with (source episode, copy) before what reads that chunk, returns
        whether it is built (False: stop here); None: the cache is built. Returns counts of the run."""
        mine = [p for p in self.missing() if p * world_size // len(self.sources) == rank]
        counts = _counts()
        bar = tqdm(total=len(mine) * (self.copies + 1), desc=f"writing episodes (rank {rank})", unit="episode",
                   position=1, disable=tty_only(progress), file=sys.stderr)  # under the cache's bar
        ready = ready or (lambda e, k: True)
        try:
            if self.workers > 1:
                if mine and self._ready(mine[0], ready):  # else nothing to hand out: no process is started
                    self._write_in_workers(mine, counts, bar, stop_after, ready)
                return counts
            for p in mine:
                for j in self._write_source(p, counts, ready):
                    if j is None:
                        return counts
                    bar.update(1)
                    if stop_after is not None and counts["episodes"] >= stop_after:
                        return counts
        finally:
            bar.close()
        return counts

    def _write_in_workers(self, mine: list[int], counts: dict, bar, stop_after: int | None, ready) -> None:
        """Write the source positions ``mine`` in ``workers`` processes (``write``; ``bar`` advanced per output
        episode). A worker's error is raised here, with its message; a worker that died, as a RunFault."""
        context = multiprocessing.get_context("spawn")  # torch is loaded: never fork
        written, stop = context.Queue(), threading.Event()
        drain = threading.Thread(target=_advance, args=(bar, written, stop), daemon=True)
        drain.start()
        state = (_detached(self.aug), self.source, self.folder, self.done, self.round_trip)
        n = min(self.workers, len(mine))
        try:
            with ProcessPoolExecutor(n, context, _start_worker, (state, written)) as pool:
                try:
                    self._hand_out(pool, n, mine, counts, stop_after, ready)
                except BaseException:
                    pool.shutdown(cancel_futures=True)
                    raise
        except BrokenProcessPool as exc:
            raise RunFault(f"export_workers: a worker process died ({exc}); re-run to resume") from exc
        finally:
            stop.set()
            drain.join()

    def _hand_out(self, pool, n: int, mine: list[int], counts: dict, stop_after: int | None, ready) -> None:
        """Start the ``n`` processes of ``pool`` (beside the build), then hand them each source position of ``mine``,
        one each at a time, once the chunks its missing episodes read are built (``ready``; stop at the first that is
        not, or once ``stop_after`` episodes are handed out); their counts added to ``counts``."""
        running, handed = {pool.submit(_open_worker) for _ in range(n)}, 0
        for p in mine:
            running = _collect(running, counts, n - 1)
            todo = self._todo(p)
            if not self._ready(p, ready):
                break
            running.add(pool.submit(_write_position, p))
            handed += len(todo)
            if stop_after is not None and handed >= stop_after:
                break
        _collect(running, counts, 0)

    def _ready(self, p: int, ready) -> bool:
        """Whether the chunks the missing episodes of source position ``p`` read are built (``ready``; the
        original reads copy 1's)."""
        return all(ready(self.sources[p], k) for k in sorted({1, *self._todo(p)} - {0}))

    def _write_source(self, p: int, counts: dict, ready):
        """Write every missing output episode of source position ``p``, each copy once ``ready`` says its chunk is
        built (the original needs copy 1's: the reference forces); yields each output episode written, None where
        a chunk is not built."""
        e, E = self.sources[p], len(self.sources)
        todo = self._todo(p)
        if not todo:
            return
        if not ready(e, 1):
            yield None
            return
        src = self._read_source(e)
        frames = src.table.column("frame_index").to_numpy().astype(int)
        first = self.aug.chunk(src.index, 1)
        for k in todo:
            j = k * E + p
            if k > 1 and not ready(e, k):
                yield None
                return
            regenerated, prov = self._copy_frames(src, k, frames, first)
            row = self._write_episode(j, src, regenerated, prov, counts)
            write_json(self._row_path(j), row)
            counts["episodes"] += 1
            yield j

    def _read_source(self, e: int) -> _Source:
        """Source episode ``e`` as its output episodes read it (``_Source``)."""
        table = self.source.episode_table(e)
        picks = sample_indices(len(table))
        videos, histograms = {}, {}
        for key in self.tactile:
            if self.source.features[key]["dtype"] == "video":
                videos[key] = self.source.video_frames(key, e)
                sampled = videos[key][picks]
            else:
                sampled = self._decode_images(table, e, key, picks)
            histograms[key] = frame_histograms(sampled)
        return _Source(e, table, picks, videos, histograms, self._shared_stats(table, e, picks))

    def _decode_images(self, table: pa.Table, e: int, key: str, rows) -> np.ndarray:
        """RGB uint8 (len(rows), H, W, 3): the PNGs of image feature ``key`` at ``rows`` of episode ``e``."""
        column, path = table.column(key).combine_chunks().field("bytes"), self.source.data_file(e)
        return np.stack(_parallel(
            lambda i: decode_png(column[int(i)].as_py(), key, f"{path} (episode {e}, frame {i})"), rows))

    def _shared_stats(self, table: pa.Table, e: int, picks: np.ndarray) -> dict:
        """Stats of the features every copy of episode ``e`` shares (``shared``: all but the tactile keys,
        provenance, episode_index and index): the source's where complete, else computed."""
        out, given = {}, self.given.get(e, {})
        for key in self.shared:
            ft = self.source.features[key]
            if complete_stats(given.get(key), ft):
                out[key] = {name: given[key][name] for name in STAT_NAMES}
            elif ft["dtype"] == "video":
                out[key] = image_stats(self.source.video_frames(key, e)[picks])
            elif ft["dtype"] == "image":
                out[key] = image_stats(self._decode_images(table, e, key, picks))
            else:
                out[key] = vector_stats(numbers(table.column(key)), key)
        return out

    def _copy_frames(self, src: _Source, k: int, frames, first) -> tuple[dict, dict]:
        """Regenerated tactile frames of copy ``k`` of ``src`` ({key: (frame positions int (n,), RGB (n, H, W,
        3))}, none in the original, k = 0) and its provenance columns."""
        L, K = len(frames), len(self.tactile)
        status = np.zeros((K, L), np.int64)
        force = np.zeros((K, L, 3), np.float32)
        offset, jitter = np.zeros(L, np.float32), np.zeros(L, np.float32)
        regenerated = {key: ([], []) for key in self.tactile}
        for j, key in enumerate(self.tactile):
            label = self.aug.keys.labels[key]
            if label is not None:
                force[j] = numbers(src.table.column(label)).reshape(L, 3)
            for i, t in enumerate(frames):
                ref = first.frames[int(t)].keys[j].reference
                if ref is not None and label is None:
                    force[j, i] = ref
        if k:
            chunk = self.aug.chunk(src.index, k)
            for j, key in enumerate(self.tactile):
                rows, images = regenerated[key]
                for i, t in enumerate(frames):
                    outcome = chunk.frames[int(t)]
                    offset[i], jitter[i] = outcome.offset, outcome.jitter
                    o = outcome.keys[j]
                    status[j, i] = o.status
                    if o.row >= 0:
                        rows.append(i)
                        images.append(chunk.files[j].read(o.row))
                        force[j, i] = o.target
        prov = {COPY: np.full(L, k, np.int64), f"{PREFIX}.offset": offset, f"{PREFIX}.jitter": jitter}
        for j, key in enumerate(self.tactile):
            prov[f"{PREFIX}.{self.names[key]}.status"] = status[j]
            prov[f"{PREFIX}.{self.names[key]}.target_force"] = force[j]
        return {key: (np.asarray(rows, int), images) for key, (rows, images) in regenerated.items()}, prov

    def _write_episode(self, j: int, src: _Source, regenerated: dict, prov: dict, counts: dict) -> dict:
        """Data file and videos of output episode ``j`` (a copy of ``src``); returns its meta row."""
        L, start, e = len(src.table), int(self.starts[j]), src.index
        out, relabelled = src.table, []
        for key, (rows, images) in regenerated.items():
            if self.source.features[key]["dtype"] == "image" and len(rows):
                out = _replace_images(out, key, rows, images)
            label = self.aug.keys.labels[key]
            if label is not None and len(rows):  # a regenerated frame's label is the force it was generated at
                forces = numbers(out.column(label)).copy()
                forces[rows] = prov[f"{PREFIX}.{self.names[key]}.target_force"][rows]
                out, relabelled = _set(out, label, forces), [*relabelled, label]
        out = _set(out, "episode_index", np.full(L, j, np.int64))
        out = _set(out, "index", np.arange(start, start + L, dtype=np.int64))
        for name, values in prov.items():
            out = out.append_column(name, _arrow(values))
        write_data_parquet(self.folder / self.source.meta["data_path"].format(
            chunk_index=j // self.chunks_size, file_index=j % self.chunks_size), out)
        writer = {"regenerated": 0, "video_sse": 0.0, "video_values": 0}
        row = {"episode_index": j, "tasks": list(self.source.episodes[e]["tasks"]), "length": L,
               "data/chunk_index": j // self.chunks_size, "data/file_index": j % self.chunks_size,
               "dataset_from_index": start, "dataset_to_index": start + L}
        for key in self.source.video_keys:
            row.update(self._video(j, src, key, regenerated.get(key), writer))
        stats = dict(src.shared)
        for key, (rows, images) in regenerated.items():
            stats[key] = tactile_stats(src.histograms[key], src.picks, rows, images)
            writer["regenerated"] += len(rows)
        for name, value in writer.items():
            counts[name] += value
        for key in ("episode_index", "index", *relabelled, *prov):
            stats[key] = vector_stats(numbers(out.column(key)), key)
        row["stats"] = {key: stats[key] for key in self.features() if key in stats}
        return {**row, "writer": writer}

    def _video(self, j: int, src: _Source, key: str, regenerated, counts: dict) -> dict:
        """meta/episodes video columns of output episode ``j``: the source's segment (copied into the folder),
        or a re-encoded file of the source's frames with the regenerated ones in place (``round_trip``: decoded
        back, its squared error over the regenerated frames counted)."""
        e = src.index
        cols = {f"videos/{key}/{c}": self.source.episodes[e][f"videos/{key}/{c}"]
                for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")}
        if regenerated is None or not len(regenerated[0]):
            path = self.source.video_path(key, e)
            dest = self.folder / path.relative_to(self.source.root)
            if not dest.is_file():
                with atomic_path(dest, ".mp4") as tmp:
                    shutil.copyfile(path, tmp)
            return cols
        rows, images = regenerated
        rgb = src.videos[key].copy()
        rgb[rows] = np.stack(images)
        number = self.first_video[key] + j - len(self.sources)
        chunk, file = number // self.chunks_size, number % self.chunks_size
        dest = self.folder / self.source.meta["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
        codec, pix_fmt = video_codec(self.source.video_path(key, e))
        encode_video(dest, rgb, self.source.fps, codec, pix_fmt)
        if self.round_trip:
            diff = decode_video(dest)[rows].astype(np.int32) - rgb[rows]
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


def _counts() -> dict:
    """A write's counts: output episodes, regenerated frames, video round trip squared error (uint8) and values."""
    return {"episodes": 0, "regenerated": 0, "video_sse": 0.0, "video_values": 0}


def _collect(jobs: set, counts: dict, most: int) -> set:
    """Wait until at most ``most`` of ``jobs`` (worker tasks) are unfinished, adding the finished ones' counts to
    ``counts`` (a worker's error raised, its message kept); returns the unfinished."""
    while True:
        for job in [job for job in jobs if job.done()]:
            for name, value in job.result().items():
                counts[name] += value
            jobs.discard(job)
        if len(jobs) <= most:
            return jobs
        wait(jobs, return_when=FIRST_COMPLETED)


def _detached(aug):
    """A copy of ``aug`` (a ForceAugment in cache mode) reading its built chunks without generator, estimator or
    dataset (the episodes' frames the chunks are checked against read first): cheap to pickle, for the workers."""
    aug.chunk_list()
    view = copy.copy(aug)
    view.generator = view.references = view.dataset = None
    return view


_WORKER: dict = {}  # a worker process's state: its export's arguments, its progress queue, the export once built


def _start_worker(state: tuple, written) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it lets the running positions finish
    _WORKER.update(state=state, written=written, export=None)


def _open_worker() -> dict:
    """A worker process's first task: its export, built here (its errors come back as this task's); no counts."""
    if _WORKER["export"] is None:
        _WORKER["export"] = LeRobotExport(*_WORKER["state"])
    return _counts()


def _write_position(p: int) -> dict:
    """A worker process's task: every missing output episode of source position ``p`` (its chunks built), each
    reported on the progress queue; returns their counts (``_counts``)."""
    _open_worker()
    counts = _counts()
    for j in _WORKER["export"]._write_source(p, counts, lambda e, k: True):
        _WORKER["written"].put(j)
    return counts


def _advance(bar, written, stop: threading.Event) -> None:
    """Advance ``bar`` per output episode the workers report on ``written``, until ``stop`` is set and all is read."""
    while not (stop.is_set() and written.empty()):
        try:
            written.get(timeout=0.1)
        except queue.Empty:
            continue
        bar.update(1)


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
    """Column ``name`` replaced by ``values`` ((N,) or (N, D)), in the column's own type."""
    i = table.schema.get_field_index(name)
    return table.set_column(i, table.schema.field(i), _arrow(values).cast(table.schema.field(i).type))


def _replace_images(table: pa.Table, key: str, rows: np.ndarray, images: list) -> pa.Table:
    """Image column ``key`` with the PNG of each regenerated frame (``images`` at ``rows``) in place (others'
    bytes kept)."""
    i = table.schema.get_field_index(key)
    cells = table.column(i).to_pylist()
    for r, data in zip(rows, _parallel(png_bytes, images)):
        cells[r] = {**cells[r], "bytes": data}
    return table.set_column(i, table.schema.field(i), pa.array(cells, type=table.schema.field(i).type))


def tactile_stats(histograms: np.ndarray, picks: np.ndarray, rows: np.ndarray, images: list) -> dict:
    """Stats of a tactile camera in a copy: the source's frame histograms at ``picks`` (int64 (len(picks), 3,
    256)), those of the regenerated frames (``images`` at ``rows``) in their place."""
    where = {int(r): n for n, r in enumerate(rows)}
    histograms = histograms.copy()
    for s, i in enumerate(picks):
        if int(i) in where:
            histograms[s] = frame_histograms(images[where[int(i)]][None])[0]
    return histogram_stats(histograms.sum(0), len(picks))
