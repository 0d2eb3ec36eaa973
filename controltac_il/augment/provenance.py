"""The cache's on-disk records: the manifest (format, settings, chunk list) and one provenance record per
(frame, tactile key) of each (episode, copy) chunk. Bump ``CACHE_FORMAT`` whenever this layout changes.

A cache is used only when it provably matches the settings: a folder without a readable manifest of this
format and these settings is refused, and so is every chunk whose ``provenance.json`` does not name the
manifest's settings (their SHA-256), generator hash and steps in its header and in every record, or does
not hold exactly one record per (frame of its episode, tactile key) (``check_chunk``)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controltac_il.augment.records import STATUS, FrameOutcome, KeyOutcome
from controltac_il.io import is_temporary_name, write_json

CACHE_FORMAT = 2
MANIFEST = "manifest.json"
PROVENANCE = "provenance.json"


class StaleCacheError(ValueError):
    """The cache folder was built with another generator, other settings or other data, or nothing proves
    that it was not (no manifest, a chunk that does not name the manifest's settings)."""


def settings_digest(settings: dict) -> str:
    """SHA-256 (hex) of a cache's settings, as each chunk records it."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class ChunkSpec:
    """What every chunk of one cache must record: the settings' digest, the generator hash and steps
    (also in each record), and the tactile keys (one record per frame and key)."""

    settings_sha256: str
    generator_hash: str
    steps: int
    tactile_keys: tuple[str, ...]

    @classmethod
    def of(cls, settings: dict) -> "ChunkSpec":
        return cls(settings_digest(settings), str(settings["generator_hash"]), int(settings["steps"]),
                   tuple(settings["tactile_keys"]))


@dataclass
class FrameRecord:
    """Provenance of one tactile image of one frame of a copy (a chunk's ``provenance.json`` row).

    status: name in STATUS; row: position of the image in the chunk's ``tactile_<j>.npy`` (-1: none
    stored); reference_force / target_force: [Fx, Fy, Fz] N or None (target_force: the force the
    generator used, after its range decision; for a skipped frame the requested one); noise_seed:
    the generator's seed (None when not generated); background: "recorded" (the items' or a given image's) |
    "estimated" (ForceAugment's own estimate); pose_offset: the
    copy's rigid contact move [dx_px, dy_px, dtheta_rad] where stage 2 moved this frame's contact, else None.
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
    pose_offset: list | None = None

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def chunk_dir(cache_dir: Path, episode: int, copy: int) -> Path:
    return cache_dir / "chunks" / f"e{episode:06d}_k{copy:03d}"


def frames_digest(cache_dir: Path) -> str:
    """sha1 (16 hex) over every chunk's generated frames (relative path and ``.npy`` bytes): equal for two caches
    exactly when they hold the same frames, wherever they were built. The manifest and the chunks' provenance are
    left out: both hold the settings' digest, which covers the source files' modification times."""
    h = hashlib.sha1()
    for path in sorted((cache_dir / "chunks").glob("*/*.npy")):
        h.update(str(path.relative_to(cache_dir)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def chunk_done(cache_dir: Path, episode: int, copy: int) -> bool:
    return (chunk_dir(cache_dir, episode, copy) / PROVENANCE).is_file()


def provenance_text(episode: int, copy: int, records: list[FrameRecord], spec: ChunkSpec) -> str:
    return json.dumps({"format": CACHE_FORMAT, "episode": episode, "copy": copy,
                       "settings_sha256": spec.settings_sha256, "generator_hash": spec.generator_hash,
                       "steps": spec.steps, "frames": [r.to_json() for r in records]}) + "\n"


def read_provenance(cache_dir: Path, episode: int, copy: int, spec: ChunkSpec | None = None,
                    frames=None) -> list[dict]:
    """The provenance records (dicts) of one chunk, checked against ``spec`` (and the episode's ``frames``)
    when given (``check_chunk``); ValueError when the chunk is not built."""
    path = chunk_dir(cache_dir, episode, copy) / PROVENANCE
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ValueError(f"cache {cache_dir}: no chunk for episode {episode} copy {copy}") from exc
    except (ValueError, UnicodeDecodeError) as exc:  # torn or edited
        raise StaleCacheError(f"cache chunk {path}: unreadable ({exc}); delete the chunk folder "
                              "(it is rebuilt by the next build)") from exc
    if spec is not None:
        check_chunk(path, doc, episode, copy, spec, frames)
    return doc["frames"]


def check_chunk(path: Path, doc, episode: int, copy: int, spec: ChunkSpec, frames=None) -> None:
    """StaleCacheError (naming the chunk and what differs) unless the chunk's provenance ``doc`` provably
    belongs to this cache: its header names ``spec``'s settings digest, generator hash and steps, and
    this episode and copy; every record names the same generator hash, steps, episode and copy; and it
    holds exactly one record per (frame, tactile key) (frames: the episode's frames, when known)."""
    def stale(what: str):
        return StaleCacheError(f"cache chunk {path.parent}: {what}; it does not provably belong to this cache "
                               "(delete the chunk folder to have it rebuilt, or the whole cache)")

    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise stale("no list of frame records")
    if doc.get("format") != CACHE_FORMAT:
        raise stale(f"format {doc.get('format')!r}, expected {CACHE_FORMAT}")
    if doc.get("settings_sha256") != spec.settings_sha256:
        raise stale(f"built with other settings (settings_sha256 {str(doc.get('settings_sha256'))[:16]!r}, "
                    f"the manifest's {spec.settings_sha256[:16]!r})")
    for name, want in (("episode", episode), ("copy", copy), ("generator_hash", spec.generator_hash),
                       ("steps", spec.steps)):
        if doc.get(name) != want:
            raise stale(f"{name}: chunk has {doc.get(name)!r}, expected {want!r}")
    seen = {k: [] for k in spec.tactile_keys}
    for n, r in enumerate(doc["frames"]):
        if not isinstance(r, dict):
            raise stale(f"record {n} is not a record")
        for name, want in (("episode", episode), ("copy", copy), ("generator_hash", spec.generator_hash),
                           ("steps", spec.steps)):
            if r.get(name) != want:
                raise stale(f"{name}: record {n} (frame {r.get('frame')!r}) has {r.get(name)!r}, expected {want!r}")
        if r.get("key") not in seen:
            raise stale(f"record {n} is of tactile key {r.get('key')!r}, not one of {list(spec.tactile_keys)}")
        if r.get("status") not in STATUS or not isinstance(r.get("row"), int) or not isinstance(r.get("frame"), int):
            raise stale(f"record {n} has no valid frame, status or row")
        seen[r["key"]].append(r["frame"])
    want_frames = sorted(frames) if frames is not None else sorted(seen[spec.tactile_keys[0]])
    for k, got in seen.items():
        if sorted(got) != want_frames or len(set(got)) != len(got):
            missing = sorted(set(want_frames) - set(got))
            raise stale(f"records of key {k!r} cover frames {_span(got)}, expected one per frame {_span(want_frames)}"
                        + (f" (missing e.g. frame {missing[0]})" if missing else ""))


def _span(frames) -> str:
    frames = sorted(frames)
    return f"{frames[0]}..{frames[-1]} ({len(frames)})" if frames else "none"


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


def _is_fresh(cache_dir: Path) -> bool:
    """No folder yet, or one holding only temporary paths of the atomic writers (a build that was just
    starting, or was killed before its manifest was in place)."""
    if not cache_dir.exists():
        return True
    return cache_dir.is_dir() and all(is_temporary_name(p.name) for p in cache_dir.iterdir())


def check_manifest(cache_dir: Path, settings: dict, chunks: list[tuple[int, int]] | None = None) -> bool:
    """Whether ``cache_dir`` is a cache of these settings (True) or a fresh folder to build one in (False);
    StaleCacheError for anything that does not provably match: a file, a folder with content but no
    readable manifest (never written over, never re-stamped), another format, other settings, another
    chunk list."""
    path = cache_dir / MANIFEST
    if cache_dir.exists() and not cache_dir.is_dir():
        raise StaleCacheError(f"cache {cache_dir}: is a file, expected a cache folder (or none)")
    if not path.is_file():
        if _is_fresh(cache_dir):
            return False
        if (cache_dir / "chunks").is_dir():
            raise StaleCacheError(
                f"cache {cache_dir}: has no {MANIFEST}, so nothing proves its chunks were built with these "
                "settings; delete the folder or use another cache folder (a cache is reused only when it "
                "provably matches)")
        raise StaleCacheError(
            f"cache {cache_dir}: not a ForceAugment cache (no {MANIFEST}) and not empty; ForceAugment builds "
            "only in a new or empty folder or completes its own cache: use another cache folder")
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict):
            raise ValueError("not a JSON object")
    except (ValueError, UnicodeDecodeError) as exc:
        raise StaleCacheError(f"cache {cache_dir}: {MANIFEST} is unreadable ({exc}); delete the folder or use "
                              "another cache folder") from exc
    if doc.get("format") != CACHE_FORMAT:
        raise StaleCacheError(f"cache {cache_dir}: format {doc.get('format')} is not {CACHE_FORMAT}; delete the "
                              "folder or use another cache folder to rebuild it")
    theirs = doc.get("settings", {})
    if not isinstance(theirs, dict):
        theirs = {}
    diff = sorted(k for k in set(settings) | set(theirs) if settings.get(k) != theirs.get(k))
    if diff:
        detail = "; ".join(f"{k}: cache has {theirs.get(k)!r}, now {settings.get(k)!r}" for k in diff[:4])
        raise StaleCacheError(
            f"cache {cache_dir} was built with other settings ({detail}); use another cache folder or "
            "delete this one (a stale cache is never reused)")
    if chunks is not None and doc.get("chunks") != [list(c) for c in chunks]:
        raise StaleCacheError(f"cache {cache_dir}: its {MANIFEST} lists other chunks than these settings make; "
                              "delete the folder or use another cache folder")
    return True


def write_manifest(cache_dir: Path, settings: dict, chunks: list[tuple[int, int]]) -> None:
    write_json(cache_dir / MANIFEST, {"format": CACHE_FORMAT, "settings": settings,
                                      "chunks": [list(c) for c in chunks]})
