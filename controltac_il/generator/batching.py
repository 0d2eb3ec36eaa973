"""How many rows a generator batch may hold: ``batch_size="auto"`` and the refusal of a batch that does not fit.

A batch of b rows at the input size (H, W) takes ``fixed + b * per_row`` bytes (a ``Footprint``): its inputs and
outputs grow with b, while the networks and the resize work one chunk at a time (``pipeline.chunk_rows``), a
fixed working set. On an accelerator the footprint is measured (its allocator's peak over a one- and a two-chunk
batch, ``ForceGenerator.footprint``); on the CPU it is counted from the arrays a batch holds. The room is the
device's free memory (CUDA: ``mem_get_info`` plus the allocator's cached blocks; CPU: the kernel's
MemAvailable) times ``HEADROOM``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from controltac_il.config import AUTO

HEADROOM = 0.8  # share of the free memory a batch may take: the allocator's fragmentation and other tensors


@dataclass(frozen=True)
class Footprint:
    """Bytes a batch takes on its device: ``fixed`` (one chunk's working set) + rows * ``per_row``."""

    fixed: int
    per_row: int

    def bytes(self, rows: int) -> int:
        return self.fixed + rows * self.per_row


def free_bytes(device: torch.device) -> int:
    """Memory a batch may take on ``device`` now, before ``HEADROOM``."""
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return int(free + torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device))
    try:
        with open("/proc/meminfo") as f:
            info = dict(line.split(":", 1) for line in f)
        return int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def largest_batch(footprint: Footprint, free: int, chunk: int) -> int:
    """The largest batch of whole chunks whose footprint fits in ``HEADROOM`` of ``free`` bytes; ValueError (one
    line) where not even one chunk does."""
    rows = int((free * HEADROOM - footprint.fixed) // max(footprint.per_row, 1)) // chunk * chunk
    if rows < chunk:
        raise ValueError(f"batch_size: not even one chunk of {chunk} rows fits ({_gb(footprint.bytes(chunk))} "
                         f"needed, {_gb(free)} free): free device memory or use smaller frames")
    return rows


def rows_per_batch(batch_size, footprint: Footprint, free: int, chunk: int, rows: int) -> int:
    """Rows per batch for ``batch_size`` (an int >= 1, or "auto": ``largest_batch``, at most ``rows``, the rows to
    generate), rounded up to whole chunks; ValueError (one line) for an int batch that does not fit."""
    if batch_size == AUTO:
        return min(largest_batch(footprint, free, chunk), -(-rows // chunk) * chunk)
    step = -(-int(batch_size) // chunk) * chunk
    need = footprint.bytes(min(step, -(-rows // chunk) * chunk))
    if need > free * HEADROOM:
        fits = "not even one chunk fits" if footprint.bytes(chunk) > free * HEADROOM else \
            f"batch_size='auto' fits {largest_batch(footprint, free, chunk)}"
        raise ValueError(f"batch_size {batch_size} does not fit: it needs {_gb(need)} and {_gb(free)} is free "
                         f"({HEADROOM:.0%} usable); {fits}")
    return step


def _gb(n: float) -> str:
    return f"{n / 2**30:.2f} GiB"
