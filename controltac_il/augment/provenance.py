"""The cache's on-disk records: the manifest (format, settings, chunk list) and one provenance record per
(frame, tactile key) of each (episode, copy) chunk. Bump ``CACHE_FORMAT`` whenever this layout changes."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controltac_il.augment.records import STATUS, FrameOutcome, KeyOutcome
from controltac_il.io import write_json

CACHE_FORMAT = 1


class StaleCacheError(ValueError):
    """The cache folder was built with another generator, other settings or other data."""


@dataclass
class FrameRecord:
    """Provenance of one tactile image of one frame of a copy (a chunk's ``provenance.json`` row).

    status: name in STATUS; row: position of the image in the chunk's ``tactile_<j>.npy`` (-1: none
    stored); reference_force / target_force: [Fx, Fy, Fz] N or None (target_force: the force the
    generator used, after its range decision; for a skipped frame the requested one); noise_seed:
    the generator's seed (None when not generated); background: "recorded" | "estimated".
    """

    episode: int
    copy: int
    frame: int
    key: str
    offset: float
    jitter: float
    reference_force: list | None
    target_force: list | None
    status: str
    row: int
    noise_seed: int | None
    generator_hash: str
    steps: int
    background: str

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def chunk_dir(cache_dir: Path, episode: int, copy: int) -> Path:
    return cache_dir / "chunks" / f"e{episode:06d}_k{copy:03d}"


def chunk_done(cache_dir: Path, episode: int, copy: int) -> bool:
    return (chunk_dir(cache_dir, episode, copy) / "provenance.json").is_file()


def provenance_text(episode: int, copy: int, records: list[FrameRecord]) -> str:
    return json.dumps({"episode": episode, "copy": copy, "frames": [r.to_json() for r in records]}) + "\n"


def read_provenance(cache_dir: Path, episode: int, copy: int) -> list[dict]:
    """The provenance records (dicts) of one chunk; ValueError when the chunk is not built."""
    try:
        doc = json.loads((chunk_dir(cache_dir, episode, copy) / "provenance.json").read_text())
    except FileNotFoundError as exc:
        raise ValueError(f"cache {cache_dir}: no chunk for episode {episode} copy {copy}") from exc
    return doc["frames"]


def frame_outcomes(records: list[dict], tactile_keys) -> dict[int, FrameOutcome]:
    """frame -> FrameOutcome (one KeyOutcome per tactile key, in ``tactile_keys`` order) of a chunk."""
    position = {k: j for j, k in enumerate(tactile_keys)}
    per_frame: dict[int, tuple] = {}
    for r in records:
        entry = per_frame.setdefault(r["frame"], (r["offset"], r["jitter"], [None] * len(position)))
        entry[2][position[r["key"]]] = KeyOutcome(
            status=STATUS[r["status"]], row=r["row"],
            reference=None if r["reference_force"] is None else np.asarray(r["reference_force"], np.float32),
            target=None if r["target_force"] is None else np.asarray(r["target_force"], np.float32))
    return {t: FrameOutcome(offset, jitter, tuple(keys)) for t, (offset, jitter, keys) in per_frame.items()}


def check_manifest(cache_dir: Path, settings: dict) -> None:
    """StaleCacheError when ``cache_dir`` holds a cache of another format or other settings."""
    path = cache_dir / "manifest.json"
    if not path.is_file():
        return
    doc = json.loads(path.read_text())
    if doc.get("format") != CACHE_FORMAT:
        raise StaleCacheError(f"cache {cache_dir}: format {doc.get('format')} is not {CACHE_FORMAT}; rebuild it")
    theirs = doc.get("settings", {})
    diff = sorted(k for k in set(settings) | set(theirs) if settings.get(k) != theirs.get(k))
    if diff:
        detail = "; ".join(f"{k}: cache has {theirs.get(k)!r}, now {settings.get(k)!r}" for k in diff[:4])
        raise StaleCacheError(
            f"cache {cache_dir} was built with other settings ({detail}); use another cache_dir or "
            "delete this one (a stale cache is never reused)")


def write_manifest(cache_dir: Path, settings: dict, chunks: list[tuple[int, int]]) -> None:
    write_json(cache_dir / "manifest.json", {"format": CACHE_FORMAT, "settings": settings,
                                             "chunks": [list(c) for c in chunks]})
