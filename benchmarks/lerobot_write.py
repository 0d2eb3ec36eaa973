"""The LeRobot writer row of ``benchmarks.augment`` (``--rows lerobot_write``): a LeRobot folder in, an augmented
LeRobot folder out, against the generator alone on the same frames.

The source (``benchmarks.lerobot_source``): gelsight_left an image feature, gelsight_right an AV1 video, two AV1
cameras, per-episode stats of every feature as ``lerobot-record`` writes them. Each round runs fresh processes,
one after the other:

- the **generator alone** (the reference), torch's OpenMP at its default wait policy (threads spin a while
  before sleeping: the generator's best): the wall and CPU seconds of its ``generate_at`` calls in a cache build
  with nothing beside it (its reading not timed);
- ``python -m controltac_il.augment --dataset ROOT --out OUT``'s **write**, timed whole: the cache build with its
  reading and, beside it, the export (PNGs, re-encoded videos, stats, meta), under each OpenMP wait policy
  (``WAIT_POLICIES``: the default, and PASSIVE, threads sleeping while they wait, which may leave the export more
  of the cores), their order alternating by round; beside the default, the same write with the **export after
  the build** (the writer without the overlap). The headline is the policy the CLI runs (``CLI_POLICY``).

Medians over rounds, wall seconds and this process's CPU seconds (``time.process_time``: every thread, torch's and
the codecs'). Target: the write at >= 0.8x the generator alone's throughput. Last, one write with
``--video-round-trip`` (every re-encoded video decoded back): its cost and its MSE (uint8 units) of the regenerated
frames, beside the generator's own error (``benchmarks/results/generator.json``)."""

from __future__ import annotations

import multiprocessing
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import load_generator, print_table
from benchmarks.lerobot_source import FORCES, write_source
from controltac_il.augment import ForceAugment
from controltac_il.augment.provenance import chunk_done
from controltac_il.lerobot import LeRobotExport, LeRobotFolder, staging_dir, write_lerobot
from controltac_il.lerobot.publish import claim, finish, signature

DEFAULT_ENV = {"OMP_WAIT_POLICY": None}  # OpenMP's own default: threads spin a while, then sleep
WAIT_POLICIES = {"openmp_default": DEFAULT_ENV, "passive": {"OMP_WAIT_POLICY": "PASSIVE"}}  # the write under each
CLI_POLICY = "openmp_default"  # what the CLI runs: it sets no policy (this row measured PASSIVE no faster, a347015)


class TimedGenerator:
    """The generator, with the wall seconds (``seconds``) and this process's CPU seconds (``cpu_seconds``, every
    thread: torch's intra-op threads run inside the call) spent in its ``generate_at`` calls summed."""

    def __init__(self, generator):
        self.generator, self.seconds, self.cpu_seconds = generator, 0.0, 0.0

    def __getattr__(self, name):
        return getattr(self.generator, name)

    def generate_at(self, *args, **kwargs):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return self.generator.generate_at(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0
            self.cpu_seconds += time.process_time() - c0


def _augment(source, gen, copies: int, steps, cache_dir: Path) -> ForceAugment:
    """ForceAugment over ``source``'s tactile streams as the CLI opens it (a folder of its own, tactile keys only)."""
    tactile_only = LeRobotFolder(source.root, keys=[*FORCES, *FORCES.values()], video_threads=0)
    return ForceAugment(tactile_only, gen, copies=copies, steps=steps, tactile_keys=list(FORCES), force_keys=FORCES,
                        cache_dir=cache_dir, build="manual", progress=False)


def generator_alone(source, cache_dir: Path, gen, copies: int, steps) -> dict:
    """Wall and CPU seconds of the generator's calls in a cache build with nothing beside it."""
    timed = TimedGenerator(gen)
    _augment(source, timed, copies, steps, cache_dir).build_cache(progress=False)
    return {"generator_seconds": timed.seconds, "generator_cpu_seconds": timed.cpu_seconds}


def timed_write(source, out: Path, gen, copies: int, steps, round_trip: bool) -> tuple[dict, dict, int]:
    """The CLI's write (cache build and export beside it), timed: (wall and CPU seconds of the whole write and of
    the generator's calls inside it, the write's record, sampler steps)."""
    timed = TimedGenerator(gen)
    t0, c0 = time.perf_counter(), time.process_time()
    aug = _augment(source, timed, copies, steps, staging_dir(out) / "cache")
    marker = write_lerobot(aug, source, out, chunk_done=chunk_done, progress=False, round_trip=round_trip)["marker"]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    times = {"write_seconds": wall, "write_cpu_seconds": cpu, "generator_seconds_in_write": timed.seconds,
             "generator_cpu_seconds_in_write": timed.cpu_seconds}
    return times, marker, aug.steps


def sequential_write(source, out: Path, gen, copies: int, steps) -> dict:
    """The same write with the export after the whole build (the build still reads ahead), left unpublished in its
    staging folder: wall and CPU seconds."""
    staging = staging_dir(out)
    t0, c0 = time.perf_counter(), time.process_time()
    aug = _augment(source, gen, copies, steps, staging / "cache")
    sig = signature(aug, source)
    claim(staging, sig)
    aug.build_cache(progress=False)
    export = LeRobotExport(aug, source, staging / "dataset", staging / "done")
    export.write(progress=False)
    finish(export, sig)
    return {"write_seconds": time.perf_counter() - t0, "write_cpu_seconds": time.process_time() - c0}


def _open(root: Path, generator: str | None, threads: int):
    torch.set_num_threads(threads)
    warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
    return LeRobotFolder(root, video_threads=0), load_generator(generator)[0]  # as the CLI opens them


def generator_job(root: Path, tmp: Path, generator: str | None, threads: int, copies: int, steps) -> dict:
    """A child process: the generator alone."""
    source, gen = _open(root, generator, threads)
    return generator_alone(source, tmp / "alone_default_env", gen, copies, steps)


def write_job(root: Path, tmp: Path, generator: str | None, threads: int, copies: int, steps, round_trip: bool,
              after: bool) -> dict:
    """A child process: the write (``round_trip``: with it), then with ``after`` the write with the export after
    the build."""
    source, gen = _open(root, generator, threads)
    times, marker, steps = timed_write(source, tmp / "write", gen, copies, steps, round_trip)
    out = {"write": times, "marker": marker, "steps": steps}
    if after:
        out["export_after_build"] = sequential_write(source, tmp / "after", gen, copies, steps)
    return out


def _set_env(values: dict) -> None:
    for name, value in values.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


def in_child(env: dict, fn, *args):
    """``fn(*args)`` in a fresh spawned process whose environment holds ``env`` (None: unset) before torch loads."""
    saved = {name: os.environ.get(name) for name in env}
    try:
        _set_env(env)
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
            return pool.submit(fn, *args).result()
    finally:
        _set_env(saved)


def _median(runs: list[dict]) -> dict:
    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def _ratios(times: dict, reference: dict) -> dict:
    return {**times, "writer_vs_generator": reference["generator_seconds"] / times["write_seconds"],
            "writer_vs_generator_cpu": reference["generator_cpu_seconds"] / times["write_cpu_seconds"],
            "writer_own_cpu_seconds": times["write_cpu_seconds"] - reference["generator_cpu_seconds"]}


def _rounds(root: Path, tmp: Path, settings: tuple, rounds: int) -> tuple[list, dict]:
    """Each round: the generator alone, then the write under each wait policy (their order alternating by round;
    the export after the build measured beside OpenMP's default). Returns (generator alone runs, {policy: runs})."""
    alone, runs = [], {name: [] for name in WAIT_POLICIES}
    for r in range(rounds):
        alone.append(in_child(DEFAULT_ENV, generator_job, root, tmp / f"round_{r}", *settings))
        for name in list(WAIT_POLICIES)[:: 1 if r % 2 == 0 else -1]:
            runs[name].append(in_child(WAIT_POLICIES[name], write_job, root, tmp / f"round_{r}_{name}", *settings,
                                       False, name == "openmp_default"))
    return alone, runs


def lerobot_write_row(tmp: Path, demos: Path, generator: str | None, threads: int, copies: int, steps,
                      rounds: int) -> dict:
    """The row (module docstring) over the ACT episodes in ``demos``."""
    root, settings = write_source(demos, tmp / "lerobot_source"), (generator, threads, copies, steps)
    alone, runs = _rounds(root, tmp, settings, rounds)
    cli = CLI_POLICY
    checked = in_child(WAIT_POLICIES[cli], write_job, root, tmp / "round_trip", *settings, True, False)
    reference = _median(alone)
    policies = {name: _ratios(_median([r["write"] for r in rs]), reference) for name, rs in runs.items()}
    write = policies[cli]
    after = _ratios(_median([r["export_after_build"] for r in runs["openmp_default"]]), reference)
    marker, n = runs[cli][0]["marker"], runs[cli][0]["marker"]["regenerated_frames"]
    row = {"regenerated_frames": n, "rounds": rounds, "cli_wait_policy": cli, **reference, **write,
           "wait_policies": policies, "export_after_build": {**after, "wait_policy": "openmp_default"},
           "writer_frames_per_s": n / write["write_seconds"], "generator_frames_per_s": n / reference["generator_seconds"],
           "target_0_8x": write["writer_vs_generator"] >= 0.8,
           "per_round": [{"generator_seconds": a["generator_seconds"],
                          **{f"write_seconds_{name}": rs[r]["write"]["write_seconds"] for name, rs in runs.items()},
                          "export_after_build_seconds": runs["openmp_default"][r]["export_after_build"]["write_seconds"]}
                         for r, a in enumerate(alone)],
           "generator_cores": reference["generator_cpu_seconds"] / reference["generator_seconds"],
           "episodes_written": marker["episodes"]["written"], "frames_written": marker["frames"],
           "video_round_trip_mse": checked["marker"]["video_round_trip_mse"],
           "video_round_trip_psnr_db": checked["marker"]["video_round_trip_psnr_db"],
           "with_round_trip": _ratios(checked["write"], reference),
           "round_trip_cpu_seconds": checked["write"]["write_cpu_seconds"] - write["write_cpu_seconds"],
           "steps": runs[cli][0]["steps"], "source": "gelsight_left image (PNG), gelsight_right AV1 video, two AV1 "
                                                     "cameras; per-episode stats of every feature, as lerobot-record "
                                                     "writes"}
    shown = [(f"export beside the build ({name})", t) for name, t in policies.items()]
    print_table([{"write": name, **reference, **t} for name, t in (
        *shown, ("export after the build (openmp_default)", after), ("with the round trip", row["with_round_trip"]))],
                ["write", "write_seconds", "generator_seconds", "writer_vs_generator", "write_cpu_seconds",
                 "generator_cpu_seconds", "writer_vs_generator_cpu"],
                title=f"LeRobot folder in, augmented LeRobot folder out (medians of {rounds} rounds; round trip: one)")
    return row
