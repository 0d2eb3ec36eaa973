"""Publishes an augmented LeRobot v3.0 folder (``write_lerobot``): staged, resumable, written by ``export`` beside
the cache build.

Everything is written under ``OUT.partial`` (``staging_dir``): ``write.json`` (what is being written: the
ForceAugment settings, the source, the writer format), ``cache/`` (the ForceAugment cache), ``dataset/`` (the folder
being written) and ``done/`` (one meta row per finished episode). Re-running the same command resumes; each rank
builds its share of the cache (torchrun: every rank) while a thread of it writes its share of the episodes, each
copy as soon as the cache holds its chunk (``ChunkGate``: the export's codecs and parquet work beside the
generator; with ``export_workers`` > 1 in that many processes, each source episode once all its chunks are built),
and rank 0 writes ``meta/`` and publishes: ``dataset/`` is renamed to OUT, and ``OUT.partial`` removed
(``write.json`` last: a removal Ctrl-C stopped is finished by the next run of the command). OUT
is never the source (nor inside it, nor around it) and never a folder this tool did not write
(``check_destination``).

The record of a write (``finish``: settings, source, counts, and with ``round_trip`` the codec's round trip over
the re-encoded videos' regenerated frames, else None) lives in ``meta/info.json`` as
``features["augment.copy"]["info"]["controltac_il_augment"]``: LeRobot's edit tools (0.4.4 and main) rebuild
info.json from the feature dicts, dropping unknown top-level keys (main) and any other file under ``meta/``.

Whether the cache holds a chunk is the cache's to say: the caller passes its ``chunk_done(cache_dir, episode,
copy)`` (``controltac_il.augment.provenance.chunk_done``, as ``python -m controltac_il.augment`` does).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np

from controltac_il.io import check_apart, write_json
from controltac_il.lerobot.export import LeRobotExport
from controltac_il.lerobot.provenance import COPY
from controltac_il.lerobot.stats import aggregate_stats
from controltac_il.lerobot.writer import write_meta

WRITER_FORMAT = 2  # bump when what is written changes
RECORD_FEATURE, RECORD_KEY = COPY, "controltac_il_augment"  # where a published folder says what wrote it
ChunkDone = Callable[[Path, int, int], bool]  # (cache_dir, episode, copy) -> whether the cache holds that chunk


def staging_dir(out: Path) -> Path:
    """Where a write to ``out`` happens until it is published."""
    out = Path(out)
    return out.with_name(out.name + ".partial")


def signature(aug, source) -> dict:
    """What a write is: the ForceAugment settings (they fix every frame), the source folder, the writer format."""
    return {"writer_format": WRITER_FORMAT, "source": str(Path(source.root).resolve()), "settings": aug.settings()}


def _digest(sig: dict) -> str:
    return hashlib.sha256(json.dumps(sig, sort_keys=True).encode()).hexdigest()[:16]


def read_record(folder: Path) -> dict | None:
    """The record of the write that made ``folder`` (module docstring), or None where it has none."""
    try:
        features = json.loads((Path(folder) / "meta" / "info.json").read_text())["features"]
        record = features[RECORD_FEATURE]["info"][RECORD_KEY]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return record if isinstance(record, dict) else None


def check_destination(root: Path, out: Path) -> bool:
    """True when ``out`` already holds this tool's finished write (``read_record`` to compare); False when it can
    be written. ValueError naming ``out`` otherwise."""
    check_apart(root, out)
    out = Path(out).resolve()
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file")
    if out.is_dir() and any(out.iterdir()):
        if read_record(out) is not None:
            return True
        raise ValueError(f"out: {out} is a non-empty folder this tool did not write; choose a new or empty folder")
    staging = staging_dir(out)
    if staging.exists() and not (staging / "write.json").is_file() and any(staging.iterdir()):
        raise ValueError(f"out: {staging} exists and was not made by this tool; move it away")
    return False


def claim(staging: Path, sig: dict) -> None:
    """Start or resume a write in ``staging``; ValueError naming ``out`` when it holds another write."""
    path = staging / "write.json"
    if path.is_file():
        if not claimed(staging, sig):
            raise ValueError(f"out: {staging} holds an unfinished write of other settings or another source; "
                             "re-run that command to finish it, or delete the folder")
        return
    staging.mkdir(parents=True, exist_ok=True)
    write_json(path, {"digest": _digest(sig), **sig})


def claimed(staging: Path, sig: dict) -> bool:
    """Whether ``staging`` holds the claim of this very write."""
    try:
        return json.loads((staging / "write.json").read_text()).get("digest") == _digest(sig)
    except (OSError, ValueError, AttributeError):
        return False


def discard(staging: Path) -> None:
    """Remove a published write's staging folder, its claim ``write.json`` last: a removal that Ctrl-C stopped is
    finished by the next run of the same write. The cache is first renamed out of ForceAugment's sight (half
    removed, it would read as a stale cache and stop that run)."""
    if (staging / "cache").is_dir():
        os.replace(staging / "cache", staging / "cache.removing")
    for child in staging.iterdir():
        if child.name != "write.json":
            shutil.rmtree(child, ignore_errors=True) if child.is_dir() and not child.is_symlink() \
                else child.unlink(missing_ok=True)
    (staging / "write.json").unlink(missing_ok=True)
    staging.rmdir()


def published(out: Path, aug, source) -> bool:
    """Whether ``out`` holds this very write (its record names the same digest); ValueError naming ``out`` for
    another write of this tool."""
    if read_record(out).get("digest") != _digest(signature(aug, source)):
        raise ValueError(f"out: {out} holds an augmented dataset of other settings or another source; choose "
                         "another folder")
    return True


class ChunkGate:
    """Lets the export wait for a chunk while the build writes them: ``built`` after each chunk, ``close`` when the
    build ends (``aborted``: it failed); ``wait(e, k)`` returns True once chunk (episode ``e``, copy ``k``) is in
    the cache (``chunk_done``), False when the build ended without it or failed. ``error``: the export's exception,
    once it failed (``fail``)."""

    def __init__(self, cache_dir: Path, chunk_done: ChunkDone):
        self.cache_dir, self.chunk_done = Path(cache_dir), chunk_done
        self._changed, self._open, self._aborted, self.error = threading.Condition(), True, False, None

    def fail(self, error: BaseException) -> None:
        self.error = error

    def built(self) -> None:
        with self._changed:
            self._changed.notify_all()

    def close(self, aborted: bool = False) -> None:
        with self._changed:
            self._open, self._aborted = False, bool(aborted)
            self._changed.notify_all()

    def wait(self, episode: int, copy: int) -> bool:
        with self._changed:
            self._changed.wait_for(lambda: not self._open or self.chunk_done(self.cache_dir, episode, copy))
            return not self._aborted and self.chunk_done(self.cache_dir, episode, copy)


def build_and_export(aug, export: LeRobotExport, rank: int, world_size: int, progress: bool, stop_after, poll_s,
                     chunk_done: ChunkDone):
    """Build this rank's chunks while a thread exports this rank's episodes as their chunks arrive (``ChunkGate``);
    an export error stops the build at its next chunk and is raised. Returns (build counts, export counts)."""
    gate = ChunkGate(aug.cache_dir, chunk_done)

    def export_episodes() -> dict:
        try:
            return export.write(rank, world_size, progress, stop_after, gate.wait)
        except BaseException as exc:
            gate.fail(exc)
            raise

    def on_chunk(episode: int, copy: int) -> None:
        if gate.error is not None:
            raise gate.error
        gate.built()

    chunks = aug.prepare_cache()  # its check of the chunks there reads them: before the export reads any
    with ThreadPoolExecutor(max_workers=1) as pool:
        job = pool.submit(export_episodes)
        try:
            built = aug.build_cache(rank=rank, world_size=world_size, progress=progress, on_chunk=on_chunk,
                                    prepared=chunks)
            aug.wait_complete(poll_s)
            gate.close()
            return built, job.result()
        except BaseException:  # the build's error, the export's, or Ctrl-C while either runs
            gate.close(aborted=True)  # the export stops after the source episode it is writing
            raise


def write_lerobot(aug, source, out: Path, *, chunk_done: ChunkDone, rank: int | None = None,
                  world_size: int | None = None, progress: bool = True, stop_after: int | None = None,
                  poll_s: float = 2.0, round_trip: bool = False, export_workers: int = 1) -> dict:
    """Write the augmented folder ``out`` of ``source`` (a LeRobotFolder, not the object ``aug`` reads: the two
    are read at once) through ``aug`` (a ForceAugment of it in cache mode whose ``cache_dir`` is
    ``staging_dir(out) / "cache"``). chunk_done: the cache's test of a chunk (module docstring). round_trip: decode
    every re-encoded video back and record the codec's round trip error over the episodes written with it on (data
    and videos are the same either way). export_workers: processes writing the output episodes, each whole source
    episodes once all their chunks are built (1: a thread of this process; the files are the same either way).
    Returns the counts of this run and, once published, the record of the write (``marker``; ``published``:
    True)."""
    out = Path(out)
    if source is aug.dataset:
        raise ValueError("source: pass a LeRobotFolder of its own (LeRobotFolder(root)), not the one ForceAugment "
                         "reads: the export reads it while the cache is built")
    if int(export_workers) < 1:
        raise ValueError(f"export_workers: expected an int >= 1 (processes writing output episodes), got "
                         f"{export_workers}")
    staging, sig = staging_dir(out), signature(aug, source)
    rank = int(os.environ.get("RANK", 0)) if rank is None else int(rank)
    world_size = int(os.environ.get("WORLD_SIZE", 1)) if world_size is None else int(world_size)
    if check_destination(source.root, out):
        done = published(out, aug, source)
        if rank == 0 and claimed(staging, sig):  # a publish that Ctrl-C stopped while it removed its staging folder
            discard(staging)
        return {"published": done, "already": True, "marker": read_record(out)}
    claim(staging, sig)
    export = LeRobotExport(aug, source, staging / "dataset", staging / "done", round_trip, export_workers)
    built, written = build_and_export(aug, export, rank, world_size, progress, stop_after, poll_s, chunk_done)
    counts = {"cache": built, **written, "published": False}
    if rank != 0 or (stop_after is not None and export.missing()):
        return counts
    together = int(os.environ.get("WORLD_SIZE", 1)) > 1  # torchrun: every rank's export ends with its share written
    while export.missing():  # other ranks' episodes
        if not together:  # ranks run one after another: what an earlier rank's export left waiting for a chunk
            export.write(progress=False, ready=lambda e, k: chunk_done(aug.cache_dir, e, k))
        if export.missing():
            time.sleep(poll_s)
    marker = finish(export, sig)
    if out.is_dir():
        out.rmdir()  # empty (check_destination)
    os.replace(staging / "dataset", out)
    discard(staging)
    return {**counts, "published": True, "marker": marker}


def finish(export: LeRobotExport, sig: dict) -> dict:
    """meta/ of the written folder (info.json with the record of the write, module docstring; episodes, stats,
    tasks); returns the record."""
    source, folder = export.source, export.folder
    rows = export.rows()
    writer = [row.pop("writer") for row in rows]
    total_frames = int(sum(row["length"] for row in rows))
    sse, values = sum(w["video_sse"] for w in writer), sum(w["video_values"] for w in writer)
    record = {"tool": "controltac_il.augment", "digest": _digest(sig), **sig,
              "episodes": {"source": len(export.sources), "copies": export.copies, "written": len(rows)},
              "frames": total_frames, "regenerated_frames": int(sum(w["regenerated"] for w in writer)),
              "video_round_trip_mse": float(sse / values) if values else None,
              "video_round_trip_psnr_db": float(10 * np.log10(255 ** 2 * values / sse)) if sse else None}
    features = export.features()
    features[RECORD_FEATURE] = {**features[RECORD_FEATURE], "info": {RECORD_KEY: record}}
    info = {**source.meta, "total_episodes": len(rows), "total_frames": total_frames,
            "splits": {"train": f"0:{len(rows)}"}, "features": features}
    write_meta(folder, info, rows, aggregate_stats([row["stats"] for row in rows]))
    for name in ("tasks", "subtasks"):
        path = source.root / "meta" / f"{name}.parquet"
        if path.is_file():
            shutil.copyfile(path, folder / "meta" / f"{name}.parquet")
    return record
