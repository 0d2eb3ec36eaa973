"""Reading the cache back: chunks opened on demand (a small per-process LRU) and one ``pread`` per image."""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controltac_il.augment.provenance import chunk_dir, frame_outcomes, read_provenance
from controltac_il.augment.records import FrameOutcome

OPEN_CHUNKS = 64  # cached chunk readers per process


class FrameFile:
    """Random row reads of a uint8 ``.npy`` stack (n, H, W, 3) with one ``pread`` per row (no page faults
    of a memory map, no HDF5 overhead): as cheap as reading a frame of the source episode."""

    def __init__(self, path: Path):
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(f)
            self.offset = f.tell()
        if dtype != np.uint8 or fortran or len(shape) != 4:
            raise ValueError(f"{path}: expected a C-ordered uint8 (n, H, W, 3) array, got {dtype} {shape}")
        self.shape = shape
        self.row_bytes = int(np.prod(shape[1:]))
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
    """Opened chunks of one cache folder, at most ``OPEN_CHUNKS`` per process (reopened after a fork)."""

    def __init__(self, cache_dir: Path, tactile_keys):
        self.cache_dir, self.tactile_keys = cache_dir, tuple(tactile_keys)
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
        records = read_provenance(self.cache_dir, episode, copy)
        d = chunk_dir(self.cache_dir, episode, copy)
        files = [FrameFile(d / f"tactile_{j}.npy") for j in range(len(self.tactile_keys))]
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
