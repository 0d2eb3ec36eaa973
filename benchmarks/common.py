"""Shared benchmark plumbing: machine header, timing by median, table printing, JSON output."""

from __future__ import annotations

import argparse
import datetime as _dt
import functools
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path
from typing import Callable, Sequence

from controltac_il.cli import ArgumentParser
from controltac_il.io import write_json


# Set by benchmarks/device_gpu.sh where the checkout's own .git cannot tell (the device tool's copy carries a stale
# one): the commit whose git tree id that script found equal to the working tree's, file for file.
VERIFIED_COMMIT = "CONTROLTAC_VERIFIED_COMMIT"


REAL_GELSIGHT = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_gelsight_mini"
"""The real GelSight Mini frames of ``../shared`` (GPL-3.0: measured against, never shipped or trained on)."""
REAL_PRESSES = ("bead", "key", "seed")  # the presses recorded with that folder's background.png


def real_gelsight(frames: Path = REAL_GELSIGHT):
    """RGB uint8 (240, 320, 3) ``background`` and ``{press: frame}`` of :data:`REAL_PRESSES` from ``frames``;
    FileNotFoundError naming the first missing file."""
    import cv2

    def rgb(name: str):
        img = cv2.imread(str(frames / f"{name}.png"))
        if img is None:
            raise FileNotFoundError(f"{frames / (name + '.png')} is missing or not an image")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    return rgb("background"), {n: rgb(n) for n in REAL_PRESSES}


def save_figure(fig, path: Path, dpi: int = 90) -> Path:
    """Write a matplotlib figure as PNG atomically (a temporary file renamed onto ``path``), then close it."""
    import matplotlib.pyplot as plt

    from controltac_il.io import atomic_path

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


def git_revision(path: Path) -> str | None:
    """Short commit of the repository holding ``path``, suffixed ``-dirty`` when tracked files
    differ from it (so a figure measured before its weights were committed says so); None
    outside a repository or without git."""
    try:
        out = subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=7", "--exclude=*"], capture_output=True,
            text=True, cwd=path, check=False,
        )
    except OSError:
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() or None


@functools.cache
def machine_info() -> dict:
    """Where and when a benchmark ran: CPU, cores, torch threads, git commit, date (UTC), taken once per
    process at its first write, so a benchmark that saves as it goes keeps the revision it started from
    (its own earlier save into a tracked results file is not a change)."""
    try:
        import torch

        torch_version, threads = torch.__version__, torch.get_num_threads()
        cuda = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    except ImportError:  # pragma: no cover - torch is a dependency
        torch_version, threads, cuda = None, None, None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    commit = os.environ.get(VERIFIED_COMMIT) or git_revision(Path(__file__).resolve().parent)
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch": torch_version,
        "torch_threads": threads,
        "cuda_device": cuda,
        "python": platform.python_version(),
        "git_commit": commit,
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def timings(fn: Callable[[], object], repeats: int = 5, warmup: int = 1,
            clock: Callable[[], float] = time.perf_counter) -> list[float]:
    """Times of ``fn()`` in seconds, ``repeats`` runs after ``warmup`` runs.

    ``clock``: ``time.perf_counter`` (wall time, default) or ``time.process_time`` (this process's CPU
    time: not inflated when other processes share the cores).
    """
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return times


def median_time(fn: Callable[[], object], repeats: int = 5, warmup: int = 1,
                clock: Callable[[], float] = time.perf_counter) -> float:
    """Median of :func:`timings` (s)."""
    return statistics.median(timings(fn, repeats, warmup, clock))


def quartiles(values: Sequence[float]) -> tuple[float, float]:
    """(25th, 75th) percentile of ``values`` (at least 2): the spread a median is quoted with."""
    q = statistics.quantiles(values, n=4, method="inclusive")
    return q[0], q[2]


def print_table(rows: Sequence[dict], columns: Sequence[str], title: str | None = None) -> None:
    """Print ``rows`` (dicts) as an aligned text table over ``columns``."""

    def fmt(v) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return "" if v is None else str(v)

    cells = [[fmt(r.get(c)) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) if cells else len(c) for i, c in enumerate(columns)]
    if title:
        print(f"\n{title}")
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths)))
    print("  ".join("-" * w for w in widths))
    for row in cells:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)))


def results_path(text: str) -> Path:
    """An --out value: a file path (written atomically, its folders made), never an existing folder."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder; expected a JSON file path")
    return path


def base_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """Argument parser of the command ``prog`` (``python -m benchmarks.NAME``, the name its errors start with)
    with the flags every benchmark takes (``--out``, ``--quick``)."""
    p = ArgumentParser(prog=prog, description=description)
    p.add_argument("--out", type=results_path, default=None, help="write the results as JSON to this file")
    p.add_argument("--quick", action="store_true", help="small version that finishes in about a minute (CI)")
    return p


def write_results(out: Path | None, results: dict) -> dict:
    """Prepend the machine header (``machine_info``) and write ``results`` to ``out`` (if given) atomically."""
    doc = {"machine": machine_info(), **results}
    if out is not None:
        write_json(out, doc)
        print(f"\nwrote {out}")
    return doc


def load_generator(path: str | None):
    """The given or shipped checkpoint; else the default architecture, randomly initialised (same speed)."""
    import torch

    from controltac_il.generator import ForceGenerator, GeneratorConfig

    try:
        return ForceGenerator.from_pretrained(path), path or "shipped default"
    except FileNotFoundError:
        if path is not None:
            raise
        from controltac_il.generator.autoencoder import TactileAutoencoder
        from controltac_il.generator.dit import ForceDiT

        torch.manual_seed(0)
        cfg = GeneratorConfig()
        gen = ForceGenerator(cfg, TactileAutoencoder(cfg.autoencoder), ForceDiT(cfg.dit), checkpoint_hash="random-init")
        return gen, "default architecture, randomly initialised (no shipped checkpoint found)"
