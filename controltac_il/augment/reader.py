"""Reading the cache back: chunks opened on demand (a small per-process LRU) and one ``pread`` per image.

Every chunk is checked when opened (``provenance.check_chunk``: settings digest, generator hash, steps,
one record per frame and key; each image file's shape and size against its records), so a chunk that
does not provably belong to the cache is refused (StaleCacheError), never read."""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controltac_il.augment.provenance import ChunkSpec, StaleCacheError, chunk_dir, frame_outcomes, read_provenance
from controltac_il.augment.records import FrameOutcome

OPEN_CHUNKS = 64  # cached chunk readers per process


class FrameFile:
    """Random row reads of a uint8 ``.npy`` stack (n, H, W, 3) with one ``pread`` per row (no page faults
    of a memory map, no HDF5 overhead): as cheap as reading a frame of the source episode."""

    def __init__(self, path: Path, rows: int | None = None):
        """rows: the number of images the chunk's records say the file holds (checked, with its size)."""
        def stale(what: str):
            return StaleCacheError(f"cache chunk {path.parent}: {path.name} {what}; it does not provably belong "
                                   "to this cache (delete the chunk folder to have it rebuilt)")

        try:
            with open(path, "rb") as f:
                version = np.lib.format.read_magic(f)
                read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                               else np.lib.format.read_array_header_2_0)
                shape, fortran, dtype = read_header(f)
                self.offset = f.tell()
                size = os.fstat(f.fileno()).st_size
        except FileNotFoundError as exc:
            raise stale("is missing") from exc
        except ValueError as exc:
            raise stale(f"is not a .npy array ({exc})") from exc
        if dtype != np.uint8 or fortran or len(shape) != 4 or shape[-1] != 3:
            raise stale(f"is not a C-ordered uint8 (n, H, W, 3) array: {dtype} {shape}")
        self.shape = shape
        self.row_bytes = int(np.prod(shape[1:]))
        if rows is not None and shape[0] != rows:
            raise stale(f"holds {shape[0]} images, its records {rows}")
        if size != self.offset + shape[0] * self.row_bytes:
            raise stale(f"has {size} bytes, {self.offset + shape[0] * self.row_bytes} expected (truncated or extended)")
        self.fd = os.open(path, os.O_RDONLY)

    def read(self, row: int) -> np.ndarray:
        out = np.empty(self.shape[1:], np.uint8)
        if os.preadv(self.fd, [out], self.offset + row * self.row_bytes) != self.row_bytes:
            raise ValueError(f"cache file truncated at row {row}")
        return out

    def close(self) -> None:
        os.close(self.fd)


@dataclass
class Chunk:
    """One (episode, copy) chunk, opened: outcome per frame, one FrameFile per tactile key, the raw records."""

    frames: dict[int, FrameOutcome]
    files: list[FrameFile]
    records: list[dict]

    def close(self) -> None:
        for f in self.files:
            f.close()


class ChunkReader:
    """Opened chunks of one cache folder, at most ``OPEN_CHUNKS`` per process (reopened after a fork).

    spec: what every chunk must record (``ChunkSpec``); frames: episode -> its frames (set by the owner
    once known; each chunk must hold exactly those)."""

    def __init__(self, cache_dir: Path, tactile_keys, spec: ChunkSpec, frames: dict | None = None):
        self.cache_dir, self.tactile_keys, self.spec, self.frames = cache_dir, tuple(tactile_keys), spec, frames
        self._open: OrderedDict = OrderedDict()
        self._pid = os.getpid()

    def __getstate__(self):
        return {**self.__dict__, "_open": OrderedDict()}

    def chunk(self, episode: int, copy: int) -> Chunk:
        if self._pid != os.getpid():
            self._open, self._pid = OrderedDict(), os.getpid()
        key = (episode, copy)
        hit = self._open.get(key)
        if hit is not None:
            self._open.move_to_end(key)
            return hit
        frames = None if self.frames is None else self.frames[episode]
        records = read_provenance(self.cache_dir, episode, copy, self.spec, frames)
        d = chunk_dir(self.cache_dir, episode, copy)
        files = []
        try:
            for j, k in enumerate(self.tactile_keys):
                rows = sorted(r["row"] for r in records if r["key"] == k and r["row"] >= 0)
                if rows != list(range(len(rows))):
                    raise StaleCacheError(f"cache chunk {d}: the rows of key {k!r} are not 0..{len(rows) - 1}; it "
                                          "does not provably belong to this cache (delete the chunk folder)")
                files.append(FrameFile(d / f"tactile_{j}.npy", len(rows)))
        except BaseException:
            for f in files:
                f.close()
            raise
        self._open[key] = hit = Chunk(frame_outcomes(records, self.tactile_keys), files, records)
        if len(self._open) > OPEN_CHUNKS:
            self._open.popitem(last=False)[1].close()
        return hit

    def frame(self, episode: int, copy: int, frame: int) -> tuple[FrameOutcome, list[FrameFile]]:
        """The outcome of one frame of a copy and the chunk's files; ValueError when the chunk lacks it."""
        c = self.chunk(episode, copy)
        outcome = c.frames.get(frame)
        if outcome is None:
            raise ValueError(f"cache {self.cache_dir}: episode {episode} copy {copy} has no frame {frame}")
        return outcome, c.files
