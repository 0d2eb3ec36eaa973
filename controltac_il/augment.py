"""ForceAugment: force-controlled tactile augmentation of an imitation-learning dataset.

    from controltac_il.augment import ForceAugment
    from controltac_il.datasets import EpisodeDataset
    dataset = ForceAugment(EpisodeDataset("demos/"), copies=4, cache_dir="cache/")  # then train as before

Index ``i`` of the wrapper is copy ``i // N`` of item ``i % N`` of the wrapped dataset (N items).
Copy 0 is the real data. Copy k >= 1 of episode e is a virtual trajectory: one normal-force offset
drawn from U[offset_range] for the whole copy, plus one jitter value per frame, added to the
reference force of every frame in contact; the generator redraws the tactile image at that target.
Every draw (offset, jitter, generator noise) is a pure function of (seed, episode, copy, frame), so
the virtual trajectory is the same in every worker, epoch, process and sampling order.

Items are the wrapped items, with only the regenerated tactile images (and their force labels, set
to the target force) replaced, plus one float32 tensor ``augment`` (K, 10) saying what was done, one
row per tactile key (order of ``ForceAugment.tactile_keys``), columns ``AUGMENT_FIELDS``::

    copy, offset, jitter          copy index (0 = real), the copy's normal-force offset and the frame's
                                  jitter, N (0 for copy 0)
    status                        STATUS code of that key's image (real, no_contact, regenerated, ...)
    ref_fx, ref_fy, ref_fz        reference force, N (NaN where not known or not needed)
    target_fx, target_fy, target_fz  force the returned image shows, N (NaN where not known)

One tensor rather than ten keeps the DataLoader fast (every tensor of a batch crosses between
processes on its own). ``ForceAugment.info(item_or_batch)`` names the columns for logging.

``mode="cache"`` generates every augmented frame once (batched) into ``cache_dir`` and reads it back;
``mode="online"`` generates on access. ``python -m controltac_il.augment --help`` builds a cache.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time
import warnings
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, Subset
from tqdm import tqdm

from controltac_il.datasets.act_dataset import EpisodeDataset
from controltac_il.datasets.background import estimate_background
from controltac_il.io import atomic_dir, write_json
from controltac_il.tactile.residual import contact_mask, from_residual, to_residual

FZ_RANGE = (1.0, 10.0)  # validated target normal force, N (paper)
SHEAR_MAX = 1.0  # validated |Fx|, |Fy|, N
CACHE_FORMAT = 1
MODES = ("cache", "online")
OUT_OF_RANGE = ("clamp", "skip")
BUILD = ("now", "require", "manual")
# Per (frame, tactile key) outcome of an augmented copy.
STATUS = {"real": 0, "no_contact": 1, "regenerated": 2, "clamped": 3, "skipped": 4}
_STATUS_NAME = {v: k for k, v in STATUS.items()}
_OPEN_CHUNKS = 64  # cached chunk readers per process
AUGMENT_FIELDS = ("copy", "offset", "jitter", "status", "ref_fx", "ref_fy", "ref_fz",
                  "target_fx", "target_fy", "target_fz")


class StaleCacheError(ValueError):
    """The cache folder was built with another generator, other settings or other data."""


@dataclass
class ForceAugmentConfig:
    """Settings of ForceAugment (everything that decides the augmented frames is recorded in the cache).

    copies: augmented copies per episode (>= 0); the wrapper has (copies + 1) x the wrapped length.
    offset_range: (low, high) N, the per-copy normal-force offset is drawn from U[low, high].
    jitter: per-frame normal-force jitter values (N), one drawn uniformly per frame.
    tactile_keys: item keys of the tactile images; None = every key containing "tactile" (but not
        "tactile_background"). A plain sensor name ``s`` means ``observation.tactile.s``.
    mode: "cache" (generate once, store, read back) or "online" (generate on access).
    cache_dir: cache folder (mode "cache"); None = a folder named after the settings under
        $CONTROLTAC_CACHE or ~/.cache/controltac_il/augment.
    out_of_range: target outside Fz in [1, 10] N, |Fx|, |Fy| <= 1 N: "clamp" it into range, or
        "skip" (keep the real frame). Both are counted.
    seed: root of every random draw (int >= 0).
    steps: sampler steps; None = the generator's default.
    contact_force: with force labels, a frame is in contact when Fz >= this (N).
    min_contact_area: without labels, a frame is in contact when at least this fraction of its
        pixels are contact pixels of ``contact_mask`` on the residual.
    batch_size: frames per generator call while building the cache.
    """

    copies: int = 4
    offset_range: tuple[float, float] = (-3.0, 10.0)
    jitter: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    tactile_keys: tuple[str, ...] | None = None
    mode: str = "cache"
    cache_dir: str | None = None
    out_of_range: str = "clamp"
    seed: int = 0
    steps: int | None = None
    contact_force: float = 0.2
    min_contact_area: float = 0.002
    batch_size: int = 32

    def __post_init__(self):
        if not isinstance(self.copies, (int, np.integer)) or isinstance(self.copies, bool) or self.copies < 0:
            raise ValueError(f"copies: expected an int >= 0, got {self.copies!r}")
        self.copies = int(self.copies)
        try:
            rng = tuple(float(v) for v in self.offset_range)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"offset_range: expected (low, high) in N, got {self.offset_range!r}") from exc
        if len(rng) != 2 or not all(math.isfinite(v) for v in rng):
            raise ValueError(f"offset_range: expected two finite numbers (low, high) in N, got {self.offset_range!r}")
        if rng[0] > rng[1]:
            raise ValueError(f"offset_range: inverted, low {rng[0]} > high {rng[1]}")
        self.offset_range = rng
        try:
            jit = tuple(float(v) for v in self.jitter)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"jitter: expected a sequence of numbers in N, got {self.jitter!r}") from exc
        if not jit or not all(math.isfinite(v) for v in jit):
            raise ValueError(f"jitter: expected a non-empty sequence of finite numbers in N, got {self.jitter!r}")
        self.jitter = jit
        if self.tactile_keys is not None:
            keys = (self.tactile_keys,) if isinstance(self.tactile_keys, str) else tuple(self.tactile_keys)
            if not keys or not all(isinstance(k, str) and k for k in keys):
                raise ValueError(f"tactile_keys: expected non-empty key names, got {self.tactile_keys!r}")
            self.tactile_keys = keys
        if self.mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {self.mode!r}")
        if self.out_of_range not in OUT_OF_RANGE:
            raise ValueError(f"out_of_range: expected one of {OUT_OF_RANGE}, got {self.out_of_range!r}")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed: expected an int >= 0, got {self.seed!r}")
        self.seed = int(self.seed)
        if self.steps is not None and (not isinstance(self.steps, (int, np.integer)) or self.steps < 1):
            raise ValueError(f"steps: expected None or an int >= 1, got {self.steps!r}")
        if not self.contact_force >= 0:
            raise ValueError(f"contact_force: expected a number >= 0 (N), got {self.contact_force!r}")
        if not 0 <= self.min_contact_area < 1:
            raise ValueError(f"min_contact_area: expected a fraction in [0, 1), got {self.min_contact_area!r}")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ValueError(f"batch_size: expected an int >= 1, got {self.batch_size!r}")


# --- the draws: pure functions of (seed, episode, copy, frame) ----------------------------------
def _stream(seed: int, *key: int) -> np.random.Generator:
    return np.random.Generator(np.random.Philox(np.random.SeedSequence(seed, spawn_key=key)))


def copy_offset(seed: int, episode: int, copy: int, offset_range: tuple[float, float]) -> float:
    """Normal-force offset (N) of copy ``copy`` of episode ``episode``: U[offset_range]."""
    return float(_stream(seed, episode, copy, 0).uniform(*offset_range))


def frame_jitter(seed: int, episode: int, copy: int, frame: int, jitter: tuple[float, ...]) -> float:
    """Jitter (N) of one frame of a copy: uniform over the ``jitter`` values."""
    return float(jitter[int(_stream(seed, episode, copy, 1, frame).integers(len(jitter)))])


def noise_seed(seed: int, episode: int, copy: int, frame: int, key_index: int) -> int:
    """Generator noise seed of one tactile image of one frame of a copy (63-bit int)."""
    return int(np.random.SeedSequence(seed, spawn_key=(episode, copy, 2, frame, key_index)).generate_state(1, np.uint64)[0] >> 1)


def resolve_target(reference: np.ndarray, delta_fz: float, out_of_range: str) -> tuple[np.ndarray, int]:
    """Target force (3,) N = reference + (0, 0, delta_fz), and its STATUS (regenerated/clamped/skipped)."""
    target = np.asarray(reference, np.float64) + np.array([0.0, 0.0, delta_fz])
    lo = np.array([-SHEAR_MAX, -SHEAR_MAX, FZ_RANGE[0]])
    hi = np.array([SHEAR_MAX, SHEAR_MAX, FZ_RANGE[1]])
    inside = bool(np.all((target >= lo) & (target <= hi)))
    if inside:
        return target, STATUS["regenerated"]
    if out_of_range == "skip":
        return target, STATUS["skipped"]
    return np.clip(target, lo, hi), STATUS["clamped"]


# --- item format helpers ------------------------------------------------------------------------
def _to_hwc_uint8(value, key: str) -> np.ndarray:
    """Tactile image of an item (tensor/array, (3, H, W) or (H, W, 3), uint8 or float in [0, 1]) -> uint8 (H, W, 3)."""
    arr = value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)
    if arr.ndim != 3 or 3 not in (arr.shape[0], arr.shape[-1]):
        raise ValueError(f"{key}: expected an RGB image (3, H, W) or (H, W, 3), got shape {arr.shape}")
    if arr.shape[0] == 3 and arr.shape[-1] != 3:
        arr = arr.transpose(1, 2, 0)
    if arr.dtype != np.uint8:
        arr = np.clip(np.round(arr.astype(np.float32) * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(arr)


def _like(image: np.ndarray, original):
    """uint8 (H, W, 3) -> the original's container, layout and dtype (None: uint8 (3, H, W) tensor view)."""
    if original is None:
        return torch.from_numpy(image).permute(2, 0, 1)
    chw = original.shape[0] == 3 and original.shape[-1] != 3
    if isinstance(original, torch.Tensor):
        out = torch.from_numpy(image)
        out = out.permute(2, 0, 1) if chw else out
        return out if original.dtype == torch.uint8 else (out.to(original.dtype) / 255.0)
    arr = image.transpose(2, 0, 1) if chw else image
    return arr if original.dtype == np.uint8 else (arr.astype(original.dtype) / 255.0)


def _default_cache_root() -> Path:
    base = os.environ.get("CONTROLTAC_CACHE")
    return Path(base) if base else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "controltac_il"


def _force_key(key: str) -> str:
    return key.replace("tactile", "force", 1)


def _background_key(key: str) -> str:
    return key.replace("tactile", "tactile_background", 1)


def _episode_source(dataset) -> tuple[EpisodeDataset | None, np.ndarray | None]:
    """The EpisodeDataset behind ``dataset`` (itself or a ``Subset`` of one) and the subset's indices.

    Those are read directly, skipping the tactile frames the cache replaces.
    """
    if isinstance(dataset, EpisodeDataset):
        return dataset, None
    if isinstance(dataset, Subset) and isinstance(dataset.dataset, EpisodeDataset) and callable(
            getattr(dataset, "frame_table", None)):
        return dataset.dataset, np.asarray(dataset.indices, np.int64)
    return None, None


class _FrameFile:
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


class _EpisodeFrames:
    """One episode's tactile residuals, contact flags and reference forces (copy-independent)."""

    def __init__(self, residuals, backgrounds, contact, reference, background_source):
        self.residuals = residuals  # key -> uint8 (T, H, W, 3)
        self.backgrounds = backgrounds  # key -> uint8 (H, W, 3)
        self.contact = contact  # key -> bool (T,)
        self.reference = reference  # key -> float64 (T, 3), NaN where unknown
        self.background_source = background_source  # key -> "recorded" | "estimated"


class ForceAugment(Dataset):
    """Wrap ``dataset`` with ``copies`` force-augmented virtual copies of every episode.

    dataset: the project's EpisodeDataset or any map-style dataset whose items are dicts with
        ``episode_index``, ``frame_index`` (ints >= 0) and tactile image tensors (LeRobot convention).
    generator: a ForceGenerator (controltac_il.generator); None = the shipped checkpoint.
    estimator: a ForceEstimator for reference forces where the items carry no force labels
        (``<key with tactile -> force>``); None = the shipped estimator, loaded only when needed.
    build: cache mode only: "now" generates the missing part of the cache at construction (this
        rank's share under torchrun, then waits for the other ranks); "require" expects a complete
        cache (error otherwise); "manual" leaves it to ``build_cache()`` (the CLI).
    Other arguments: see ForceAugmentConfig.
    """

    def __init__(self, dataset, generator=None, copies=4, offset_range=(-3.0, 10.0),
                 jitter=(-1.0, -0.5, 0.0, 0.5, 1.0), tactile_keys=None, mode="cache", cache_dir=None,
                 out_of_range="clamp", seed=0, steps=None, *, estimator=None, contact_force=0.2,
                 min_contact_area=0.002, batch_size=32, build="now", progress=True):
        self.config = ForceAugmentConfig(
            copies=copies, offset_range=offset_range, jitter=jitter, tactile_keys=tactile_keys, mode=mode,
            cache_dir=None if cache_dir is None else str(cache_dir), out_of_range=out_of_range, seed=seed,
            steps=steps, contact_force=contact_force, min_contact_area=min_contact_area, batch_size=batch_size)
        self.dataset = dataset
        self.n_base = len(dataset)
        if self.n_base == 0:
            raise ValueError("dataset: is empty")
        probe = dataset[0]
        if not isinstance(probe, dict):
            raise ValueError(f"dataset: items must be dicts (LeRobot convention), got {type(probe).__name__}")
        for k in ("episode_index", "frame_index"):
            if k not in probe:
                raise ValueError(f"dataset: items have no {k!r}; ForceAugment needs 'episode_index' and 'frame_index' per item")
        self.tactile_keys = self._resolve_keys(probe)
        self.labelled = {k: _force_key(k) in probe for k in self.tactile_keys}
        self.progress = progress
        if generator is None:
            from controltac_il.generator import ForceGenerator

            generator = ForceGenerator.from_pretrained()
        self.generator = generator
        self.steps = int(self.config.steps if self.config.steps is not None else generator.config.default_steps)
        self._estimator = estimator
        self._chunks: OrderedDict = OrderedDict()
        self._pid = os.getpid()
        self._frames = None  # (episode, frame) per index, when known without reading items
        self._source, self._source_index = None, None  # EpisodeDataset read directly (cache mode)
        if self.config.mode == "online":
            missing = [k for k in self.tactile_keys if _background_key(k) not in probe]
            if missing:
                raise ValueError(
                    f"tactile_keys: items carry no {_background_key(missing[0])!r}; online mode needs the "
                    "no-contact background in each item (use mode='cache', which estimates it per episode)")
            self.cache_dir = None
        else:
            self.cache_dir = Path(self.config.cache_dir) if self.config.cache_dir else self._default_cache_dir()
            self._source, self._source_index = _episode_source(dataset)
            if self._source is not None:
                self._frames = dataset.frame_table()
            self._check_manifest()
            if build not in BUILD:
                raise ValueError(f"build: expected one of {BUILD}, got {build!r}")
            if build == "now":
                self.build_cache(progress=progress)
                self._wait_complete()
            if build != "manual":
                self._require_complete()

    # --- set-up ---------------------------------------------------------------------------------
    def _resolve_keys(self, probe: dict) -> tuple[str, ...]:
        found = [k for k in probe if "tactile" in k and "tactile_background" not in k]
        if self.config.tactile_keys is None:
            if not found:
                raise ValueError("tactile_keys: the items have no key containing 'tactile'; pass tactile_keys=")
            keys = tuple(found)
        else:
            keys = []
            for k in self.config.tactile_keys:
                full = k if k in probe else f"observation.tactile.{k}"
                if full not in probe:
                    raise ValueError(f"tactile_keys: unknown tactile key {k!r}; the items have {found or list(probe)}")
                keys.append(full)
            keys = tuple(keys)
        for k in keys:
            _to_hwc_uint8(probe[k], k)
        return keys

    @property
    def estimator(self):
        """The force estimator (loaded on first use); a clear error when it is not available."""
        if self._estimator is None:
            try:
                from controltac_il.estimators import ForceEstimator

                self._estimator = ForceEstimator.from_pretrained()
            except (ImportError, FileNotFoundError, OSError) as exc:
                unlabelled = [k for k, v in self.labelled.items() if not v]
                raise RuntimeError(
                    f"ForceAugment: the items carry no force labels for {unlabelled}, so reference forces "
                    f"must come from a force estimator, and none could be loaded ({exc}); pass "
                    "estimator=ForceEstimator.from_pretrained(PATH) or record force labels") from exc
        return self._estimator

    def settings(self) -> dict:
        """Everything that decides the augmented frames (compared against a cache's manifest)."""
        cfg = asdict(self.config)
        for k in ("mode", "cache_dir", "batch_size"):  # do not change the frames
            cfg.pop(k)
        cfg["steps"] = self.steps
        cfg["tactile_keys"] = list(self.tactile_keys)
        cfg["generator_hash"] = str(self.generator.checkpoint_hash)
        cfg["reference_force"] = {k: ("labels" if v else "estimator") for k, v in self.labelled.items()}
        if not all(self.labelled.values()):
            cfg["estimator_hash"] = str(getattr(self.estimator, "checkpoint_hash", None))
        source, index = _episode_source(self.dataset)
        fp = getattr(source if source is not None else self.dataset, "fingerprint", None)
        data = dict(fp()) if callable(fp) else {}
        data.pop("root", None)
        if index is not None:
            data["subset_sha256"] = hashlib.sha256(np.asarray(index, np.int64).tobytes()).hexdigest()[:16]
        cfg["data"] = {"type": type(self.dataset).__name__, "length": self.n_base, **data}
        return json.loads(json.dumps(cfg))

    def _default_cache_dir(self) -> Path:
        digest = hashlib.sha256(json.dumps(self.settings(), sort_keys=True).encode()).hexdigest()[:16]
        return _default_cache_root() / "augment" / digest

    def _check_manifest(self) -> None:
        path = self.cache_dir / "manifest.json"
        if not path.is_file():
            return
        doc = json.loads(path.read_text())
        if doc.get("format") != CACHE_FORMAT:
            raise StaleCacheError(f"cache {self.cache_dir}: format {doc.get('format')} is not {CACHE_FORMAT}; rebuild it")
        mine = self.settings()
        theirs = doc.get("settings", {})
        diff = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        if diff:
            detail = "; ".join(f"{k}: cache has {theirs.get(k)!r}, now {mine.get(k)!r}" for k in diff[:4])
            raise StaleCacheError(
                f"cache {self.cache_dir} was built with other settings ({detail}); use another cache_dir or "
                "delete this one (a stale cache is never reused)")

    # --- size and indexing ----------------------------------------------------------------------
    def __len__(self) -> int:
        return (self.config.copies + 1) * self.n_base

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_chunks"] = OrderedDict()
        return state

    def __getitem__(self, index: int) -> dict:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"index {index} out of range for {n} items")
        copy, base = divmod(int(index) % n, self.n_base)
        if copy and self._frames is not None:  # the project's dataset: do not read frames about to be replaced
            episode, frame = int(self._frames[0][base]), int(self._frames[1][base])
            entry = self._chunk(episode, copy)[0].get(frame)
            regenerated = [k for k, e in zip(self.tactile_keys, entry[2]) if e[1] >= 0] if entry else []
            src = base if self._source_index is None else int(self._source_index[base])
            return self._from_cache(self._source.item(src, skip_keys=regenerated), episode, copy, frame)
        item = dict(self.dataset[base])
        if copy == 0:
            return self._annotate(item, 0, 0.0, 0.0, {k: (STATUS["real"], None, None) for k in self.tactile_keys})
        episode, frame = self._episode_frame(item)
        if self.config.mode == "cache":
            return self._from_cache(item, episode, copy, frame)
        return self._online(item, episode, copy, frame)

    @staticmethod
    def _episode_frame(item: dict) -> tuple[int, int]:
        try:
            e, t = int(item["episode_index"]), int(item["frame_index"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError("dataset: items need integer 'episode_index' and 'frame_index'") from exc
        if e < 0 or t < 0:
            raise ValueError(f"dataset: episode_index and frame_index must be >= 0, got {e}, {t}")
        return e, t

    def _annotate(self, item: dict, copy: int, offset: float, jitter: float, per_key: dict, has_row=False) -> dict:
        """Add ``augment`` (K, 10). per_key: key -> (status, reference (3,) or None, target (3,) or None),
        or with ``has_row`` (status, row, reference, target)."""
        rows = np.full((len(per_key), len(AUGMENT_FIELDS)), np.nan, np.float32)
        rows[:, :3] = copy, offset, jitter
        for i, (k, rec) in enumerate(per_key.items()):
            status, ref, target = (rec[0], rec[2], rec[3]) if has_row else rec
            if ref is None and self.labelled[k]:
                ref = item[_force_key(k)]
            rows[i, 3] = status
            if ref is not None:
                rows[i, 4:7] = ref
            shown = target if status in (STATUS["regenerated"], STATUS["clamped"]) else ref
            if shown is not None:
                rows[i, 7:10] = shown
        item["augment"] = torch.from_numpy(rows)
        return item

    def info(self, item: dict) -> dict:
        """Named columns of ``item["augment"]`` (an item's (K, 10) or a batch's (B, K, 10)), for logging:
        copy, offset, jitter, augmented (any key regenerated), and per tactile key ``status.<key>``,
        ``reference_force.<key>`` (..., 3), ``target_force.<key>`` (..., 3)."""
        a = item["augment"]
        status = a[..., 3].long()
        out = {"copy": a[..., 0, 0].long(), "offset": a[..., 0, 1], "jitter": a[..., 0, 2],
               "augmented": ((status == STATUS["regenerated"]) | (status == STATUS["clamped"])).any(-1)}
        for i, k in enumerate(self.tactile_keys):
            out[f"status.{k}"] = status[..., i]
            out[f"reference_force.{k}"] = a[..., i, 4:7]
            out[f"target_force.{k}"] = a[..., i, 7:10]
        return out

    def _replace(self, item: dict, key: str, image: np.ndarray, target) -> None:
        item[key] = _like(image, item.get(key))
        fk = _force_key(key)
        if fk in item:
            orig = item[fk]
            t = target.numpy() if isinstance(target, torch.Tensor) else np.asarray(target)
            if isinstance(orig, torch.Tensor):
                item[fk] = torch.from_numpy(t.astype(np.float32)).to(orig.dtype)
            else:
                item[fk] = t.astype(np.asarray(orig).dtype)

    # --- online mode ----------------------------------------------------------------------------
    def _online(self, item: dict, episode: int, copy: int, frame: int) -> dict:
        cfg = self.config
        offset = copy_offset(cfg.seed, episode, copy, cfg.offset_range)
        jitter = frame_jitter(cfg.seed, episode, copy, frame, cfg.jitter)
        per_key = {}
        for j, k in enumerate(self.tactile_keys):
            image = _to_hwc_uint8(item[k], k)
            background = _to_hwc_uint8(item[_background_key(k)], _background_key(k))
            residual = to_residual(image, background)
            label = np.asarray(item[_force_key(k)], np.float64) if self.labelled[k] else None
            if not self._in_contact(residual[None], None if label is None else label[None])[0]:
                per_key[k] = (STATUS["no_contact"], None, None)
                continue
            ref = label if label is not None else self.estimator.predict(residual[None])[0].astype(np.float64)
            target, status = resolve_target(ref, offset + jitter, cfg.out_of_range)
            if status != STATUS["skipped"]:
                out = self._generate(residual[None], ref[None], target[None], [noise_seed(cfg.seed, episode, copy, frame, j)])
                self._replace(item, k, from_residual(out[0], background), target)
            per_key[k] = (status, ref, target)
        return self._annotate(item, copy, offset, jitter, per_key)

    def _in_contact(self, residuals: np.ndarray, labels: np.ndarray | None) -> np.ndarray:
        """bool (T,): Fz >= contact_force with labels, else enough contact pixels in the residual."""
        if labels is not None:
            return labels[:, 2] >= self.config.contact_force
        area = contact_mask(residuals).mean(axis=(1, 2))
        return (area >= self.config.min_contact_area) & (area > 0)

    def _generate(self, residuals, reference, target, seeds) -> np.ndarray:
        """Generator call for residuals uint8 (B, H, W, 3) at ``target`` (B, 3) from ``reference`` (B, 3)."""
        return self.generator.generate(
            residuals, target - reference, steps=self.steps, seed=list(seeds), batch_size=self.config.batch_size,
            reference_force=reference, out_of_range="clamp")

    # --- cache mode: layout ---------------------------------------------------------------------
    def _chunk_dir(self, episode: int, copy: int) -> Path:
        return self.cache_dir / "chunks" / f"e{episode:06d}_k{copy:03d}"

    def _episodes(self) -> "OrderedDict[int, list[tuple[int, int]]]":
        """episode -> [(frame, dataset index)] sorted by frame (from ``frame_table()`` when the dataset has it)."""
        table = getattr(self.dataset, "frame_table", None)
        if callable(table):
            eps, frames = table()
        else:
            eps, frames = np.empty(self.n_base, np.int64), np.empty(self.n_base, np.int64)
            for i in tqdm(range(self.n_base), desc="scanning", disable=not self.progress, file=sys.stderr):
                eps[i], frames[i] = self._episode_frame(self.dataset[i])
        out: OrderedDict = OrderedDict()
        for i in np.lexsort((frames, eps)):
            out.setdefault(int(eps[i]), []).append((int(frames[i]), int(i)))
        return out

    def chunk_list(self) -> list[tuple[int, int]]:
        """Every (episode, copy) chunk of the cache, in build order."""
        return [(e, k) for e in self._episode_ids() for k in range(1, self.config.copies + 1)]

    def _episode_ids(self) -> list[int]:
        if not hasattr(self, "_episode_cache"):
            self._episode_cache = self._episodes()
        return list(self._episode_cache)

    def missing_chunks(self) -> list[tuple[int, int]]:
        return [c for c in self.chunk_list() if not (self._chunk_dir(*c) / "provenance.json").is_file()]

    # --- cache mode: build ----------------------------------------------------------------------
    def build_cache(self, rank: int | None = None, world_size: int | None = None, progress: bool = True,
                    stop_after: int | None = None) -> dict:
        """Generate this rank's missing chunks (rank/world_size default to torchrun's RANK/WORLD_SIZE).

        Chunk j of ``chunk_list()`` belongs to rank ``j * world_size // len(chunks)``; each chunk is
        written atomically, so an interrupted build resumes where it stopped and equals a clean one.
        stop_after: stop after writing this many chunks (to split a build). Returns counts of the run.
        """
        if self.config.mode != "cache":
            raise ValueError("build_cache: only in mode='cache'")
        rank = int(os.environ.get("RANK", 0)) if rank is None else int(rank)
        world_size = int(os.environ.get("WORLD_SIZE", 1)) if world_size is None else int(world_size)
        if not 0 <= rank < world_size:
            raise ValueError(f"rank: expected 0 <= rank < world_size={world_size}, got {rank}")
        self._check_manifest()
        chunks = self.chunk_list()
        write_json(self.cache_dir / "manifest.json", {
            "format": CACHE_FORMAT, "settings": self.settings(), "chunks": [list(c) for c in chunks]})
        mine = [c for j, c in enumerate(chunks) if j * world_size // max(len(chunks), 1) == rank]
        todo = [c for c in mine if not (self._chunk_dir(*c) / "provenance.json").is_file()]
        if stop_after is not None:
            todo = todo[:stop_after]
        lengths = {e: len(v) for e, v in self._episode_cache.items()}
        counts = {"chunks": 0, "frames": 0, "generated": 0, "seconds": 0.0}
        t0 = time.perf_counter()
        bar = tqdm(total=sum(lengths[e] for e, _ in todo), unit="frame", desc=f"ForceAugment cache (rank {rank})",
                   disable=not progress, file=sys.stderr)
        current, frames = None, None
        for e, k in todo:
            if e != current:
                current, frames = e, self._load_episode(e)
            counts["generated"] += self._write_chunk(e, k, frames)
            counts["chunks"] += 1
            counts["frames"] += lengths[e]
            bar.update(lengths[e])
        bar.close()
        counts["seconds"] = time.perf_counter() - t0
        return counts

    def _load_episode(self, episode: int) -> _EpisodeFrames:
        rows = self._episode_cache[episode]
        items = [self.dataset[i] for _, i in rows]
        for (t, _), it in zip(rows, items):
            if self._episode_frame(it) != (episode, t):
                raise ValueError(f"dataset: item order changed while building (episode {episode}, frame {t})")
        residuals, backgrounds, contact, reference, source = {}, {}, {}, {}, {}
        for k in self.tactile_keys:
            images = np.stack([_to_hwc_uint8(it[k], k) for it in items])
            labels = np.stack([np.asarray(it[_force_key(k)], np.float64) for it in items]) if self.labelled[k] else None
            bkey = _background_key(k)
            if bkey in items[0]:
                bg, source[k] = _to_hwc_uint8(items[0][bkey], bkey), "recorded"
            else:
                bg, used = estimate_background(images, labels)
                source[k] = "estimated"
                warnings.warn(f"episode {episode}: items carry no {bkey!r}; background estimated from "
                              f"{len(used)} no-contact frames", stacklevel=2)
            res = to_residual(images, bg)
            touch = self._in_contact(res, labels)
            ref = np.full((len(items), 3), np.nan)
            if labels is not None:
                ref[:] = labels
            elif touch.any():
                ref[touch] = self.estimator.predict(res[touch]).astype(np.float64)
            residuals[k], backgrounds[k], contact[k], reference[k] = res, bg, touch, ref
        return _EpisodeFrames(residuals, backgrounds, contact, reference, source)

    def _plan_chunk(self, episode: int, copy: int, ep: _EpisodeFrames) -> list[dict]:
        """Provenance records of one chunk (every frame x tactile key), before generation.

        A record to generate has ``row`` >= 0: its position in the chunk's image array of its key.
        """
        cfg = self.config
        frames = [t for t, _ in self._episode_cache[episode]]
        offset = copy_offset(cfg.seed, episode, copy, cfg.offset_range)
        records = []
        for j, k in enumerate(self.tactile_keys):
            rows = 0
            for i, t in enumerate(frames):
                rec = {"episode": episode, "copy": copy, "frame": t, "key": k, "offset": offset,
                       "jitter": frame_jitter(cfg.seed, episode, copy, t, cfg.jitter), "reference_force": None,
                       "target_force": None, "status": "no_contact", "row": -1, "noise_seed": None,
                       "generator_hash": str(self.generator.checkpoint_hash), "steps": self.steps,
                       "background": ep.background_source[k]}
                if ep.contact[k][i]:
                    ref = ep.reference[k][i]
                    target, status = resolve_target(ref, offset + rec["jitter"], cfg.out_of_range)
                    rec.update(reference_force=ref.tolist(), target_force=target.tolist(), status=_STATUS_NAME[status])
                    if status != STATUS["skipped"]:
                        rec.update(row=rows, noise_seed=noise_seed(cfg.seed, episode, copy, t, j))
                        rows += 1
                records.append(rec)
        return records

    def _write_chunk(self, episode: int, copy: int, ep: _EpisodeFrames) -> int:
        records = self._plan_chunk(episode, copy, ep)
        position = {t: i for i, (t, _) in enumerate(self._episode_cache[episode])}
        todo = [r for r in records if r["row"] >= 0]  # every key of the chunk in one generator call
        if todo:
            refs = np.stack([ep.residuals[r["key"]][position[r["frame"]]] for r in todo])
            out = self._generate(refs, np.asarray([r["reference_force"] for r in todo]),
                                 np.asarray([r["target_force"] for r in todo]), [r["noise_seed"] for r in todo])
        with atomic_dir(self._chunk_dir(episode, copy)) as tmp:
            for j, k in enumerate(self.tactile_keys):
                mine = [i for i, r in enumerate(todo) if r["key"] == k]
                h, w = ep.residuals[k].shape[1:3]
                images = from_residual(out[mine], ep.backgrounds[k]) if mine else np.empty((0, h, w, 3), np.uint8)
                np.save(tmp / f"tactile_{j}.npy", images)
            (tmp / "provenance.json").write_text(json.dumps({"episode": episode, "copy": copy, "frames": records}) + "\n")
        return len(todo)

    def plan(self, progress: bool = False) -> list[dict]:
        """Provenance records of every augmented frame without generating (reads the whole dataset once).

        Lets a user count contact / clamped / skipped frames before building, or in online mode.
        """
        out = []
        for e in tqdm(self._episode_ids(), desc="planning", disable=not progress, file=sys.stderr):
            ep = self._load_episode(e)
            for k in range(1, self.config.copies + 1):
                out.extend(self._plan_chunk(e, k, ep))
        return out

    def _wait_complete(self, poll_s: float = 2.0) -> None:
        """Under torchrun, wait until the other ranks have written their chunks."""
        if int(os.environ.get("WORLD_SIZE", 1)) <= 1:
            return
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            torch.distributed.barrier()
            return
        while self.missing_chunks():
            time.sleep(poll_s)

    def _require_complete(self) -> None:
        missing = self.missing_chunks()
        if missing:
            raise ValueError(f"cache {self.cache_dir}: {len(missing)} chunk(s) missing, e.g. episode {missing[0][0]} "
                             f"copy {missing[0][1]}; build it (python -m controltac_il.augment) or pass build='now'")

    # --- cache mode: read -----------------------------------------------------------------------
    def _chunk(self, episode: int, copy: int):
        if self._pid != os.getpid():
            self._chunks, self._pid = OrderedDict(), os.getpid()
        key = (episode, copy)
        hit = self._chunks.get(key)
        if hit is not None:
            self._chunks.move_to_end(key)
            return hit
        d = self._chunk_dir(episode, copy)
        try:
            doc = json.loads((d / "provenance.json").read_text())
        except FileNotFoundError as exc:
            raise ValueError(f"cache {self.cache_dir}: no chunk for episode {episode} copy {copy}") from exc
        # frame -> (offset, jitter, per key (status, row, reference (3,)|None, target (3,)|None))
        frames: dict = {}
        position = {k: j for j, k in enumerate(self.tactile_keys)}
        for r in doc["frames"]:
            entry = frames.setdefault(r["frame"], (r["offset"], r["jitter"], [None] * len(position)))
            entry[2][position[r["key"]]] = (
                STATUS[r["status"]], r["row"],
                None if r["reference_force"] is None else np.asarray(r["reference_force"], np.float32),
                None if r["target_force"] is None else np.asarray(r["target_force"], np.float32))
        files = [_FrameFile(d / f"tactile_{j}.npy") for j in range(len(self.tactile_keys))]
        self._chunks[key] = hit = (frames, files, doc["frames"])
        if len(self._chunks) > _OPEN_CHUNKS:
            for f in self._chunks.popitem(last=False)[1][1]:
                f.close()
        return hit

    def _from_cache(self, item: dict, episode: int, copy: int, frame: int) -> dict:
        frames, files, _ = self._chunk(episode, copy)
        entry = frames.get(frame)
        if entry is None:
            raise ValueError(f"cache {self.cache_dir}: episode {episode} copy {copy} has no frame {frame}")
        offset, jitter, per_key = entry
        for j, (k, (status, row, ref, target)) in enumerate(zip(self.tactile_keys, per_key)):
            if row >= 0:
                self._replace(item, k, files[j].read(row), target)
        return self._annotate(item, copy, offset, jitter, dict(zip(self.tactile_keys, per_key)), has_row=True)

    def provenance(self) -> list[dict]:
        """Every augmented frame's record (cache mode): episode, copy, frame, key, offset, jitter,
        reference and target force, status, generator hash, steps, noise seed."""
        if self.config.mode != "cache":
            raise ValueError("provenance: only in mode='cache'")
        out = []
        for e, k in self.chunk_list():
            out.extend(self._chunk(e, k)[2])
        return out

    def summary(self) -> dict:
        """Counts over the augmented copies: tactile frames, no_contact, regenerated, clamped, skipped.

        From the cache's provenance in cache mode; from ``plan()`` (one pass over the data) online.
        """
        recs = self.provenance() if self.config.mode == "cache" else self.plan()
        counts = {name: 0 for name in ("no_contact", "regenerated", "clamped", "skipped")}
        for r in recs:
            counts[r["status"]] += 1
        total = len(recs)
        return {"tactile_frames": total, **counts,
                "fraction_regenerated": (counts["regenerated"] + counts["clamped"]) / total if total else 0.0}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m controltac_il.augment",
        description="Build a ForceAugment cache: generate every augmented tactile frame of a folder of ACT "
                    "episodes once (batched), with provenance. Resumable (re-run the same command) and "
                    "shardable (torchrun --nproc_per_node N -m controltac_il.augment ...).")
    p.add_argument("--dataset", required=True, type=Path, help="folder of episode_<i>.hdf5 files (read-only)")
    p.add_argument("--out", required=True, type=Path, help="cache folder to create or complete")
    p.add_argument("--copies", type=int, default=4, help="augmented copies per episode (default 4)")
    p.add_argument("--offset-range", type=float, nargs=2, default=(-3.0, 10.0), metavar=("LOW", "HIGH"),
                   help="per-copy normal-force offset range, N (default -3 10)")
    p.add_argument("--jitter", type=float, nargs="+", default=[-1.0, -0.5, 0.0, 0.5, 1.0],
                   help="per-frame jitter values, N (default -1 -0.5 0 0.5 1)")
    p.add_argument("--tactile-keys", nargs="+", default=None, help="tactile sensors to augment (default all)")
    p.add_argument("--out-of-range", choices=OUT_OF_RANGE, default="clamp",
                   help="target outside Fz in [1, 10] N: clamp it, or skip (keep the real frame)")
    p.add_argument("--seed", type=int, default=0, help="root of every random draw (default 0)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the generator's)")
    p.add_argument("--generator", default=None, help="generator checkpoint folder (default: shipped)")
    p.add_argument("--estimator", default=None, help="force estimator checkpoint (only for data without force labels)")
    p.add_argument("--batch-size", type=int, default=32, help="frames per generator call (default 32)")
    p.add_argument("--device", default="cpu", help="torch device for the generator (default cpu)")
    args = p.parse_args(argv)

    from controltac_il.generator import ForceGenerator

    estimator = None
    if args.estimator:
        from controltac_il.estimators import ForceEstimator

        estimator = ForceEstimator.from_pretrained(args.estimator)
    dataset = EpisodeDataset(args.dataset, chunk_size=1, cameras=[])
    aug = ForceAugment(dataset, ForceGenerator.from_pretrained(args.generator, device=args.device),
                       copies=args.copies, offset_range=tuple(args.offset_range), jitter=tuple(args.jitter),
                       tactile_keys=args.tactile_keys, cache_dir=args.out, out_of_range=args.out_of_range,
                       seed=args.seed, steps=args.steps, estimator=estimator, batch_size=args.batch_size,
                       build="manual", progress=True)
    counts = aug.build_cache()
    rate = counts["generated"] / counts["seconds"] if counts["seconds"] > 0 else float("nan")
    print(f"wrote {counts['chunks']} chunk(s), {counts['generated']} generated frames in "
          f"{counts['seconds']:.1f} s ({rate:.2f} frames/s) to {aug.cache_dir}")
    missing = aug.missing_chunks()
    if missing:
        print(f"{len(missing)} chunk(s) left to other ranks or a later run")
    else:
        s = aug.summary()
        print(f"cache complete: {s['tactile_frames']} augmented tactile frames, {s['regenerated']} regenerated, "
              f"{s['clamped']} clamped, {s['skipped']} skipped (kept real), {s['no_contact']} without contact")
    return 0


if __name__ == "__main__":
    sys.exit(main())
