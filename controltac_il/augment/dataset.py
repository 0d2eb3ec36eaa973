"""``ForceAugment``: the dataset wrapper (indexing, set-up, the cache's life cycle, summaries)."""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from collections import OrderedDict
from dataclasses import asdict
from pathlib import Path

import numpy as np
from torch.utils.data import Dataset
from tqdm import tqdm

from controltac_il.arrays import as_index
from controltac_il.cli import tty_only

from controltac_il.augment import items as adapters
from controltac_il.augment.config import BUILD, ForceAugmentConfig
from controltac_il.augment.keys import resolve_keys
from controltac_il.augment.online import EpisodeTables, OnlineGenerator
from controltac_il.augment.provenance import CACHE_FORMAT, ChunkSpec, chunk_done, check_manifest, write_manifest
from controltac_il.augment.reader import ChunkReader
from controltac_il.augment.records import STATUS, FrameOutcome, KeyOutcome, annotate, info
from controltac_il.augment.reference import EpisodeFrames, ReferenceForces, bundle_estimator, estimator_at
from controltac_il.augment.writer import CacheWriter
from controltac_il.config import is_int
from controltac_il.io import cache_root, remove_leftovers


class ForceAugment(Dataset):
    """Wrap ``dataset`` with ``copies`` force-augmented virtual copies of every episode.

    dataset: the project's EpisodeDataset or any map-style dataset whose items are dicts with
        ``episode_index``, ``frame_index`` (ints >= 0) and tactile images (LeRobot convention: a tactile
        stream is a camera ``observation.images.<name>``, named in ``tactile_keys``; float CHW in [0, 1] or
        uint8, single frames or ``delta_timestamps`` windows with ``<key>_is_pad``; see ``keys``).
    generator: a ForceGenerator (controltac_il.generator), a checkpoint folder, or a calibration bundle
        (``python -m controltac_il.calibrate``); None = the shipped checkpoint.
    estimator: a ForceEstimator (or its checkpoint folder, or a calibration bundle) for reference forces where the
        items carry no force labels (``force_keys``); None = the bundle's estimator where ``generator`` names a
        bundle, else the shipped estimator, loaded only when needed.
    build: cache mode only: "now" generates the missing part of the cache at construction (this
        rank's share under torchrun, then waits for the other ranks); "require" expects a complete
        cache (error otherwise); "manual" leaves it to ``build_cache()`` (the CLI).
    A cache is used only when it provably matches (else StaleCacheError, naming the folder and what
    differs): its manifest holds these settings, and every chunk names them (``provenance.check_chunk``);
    a folder with content but no manifest is never used nor written into.
    settings: the ``ForceAugmentConfig`` fields (copies, offset_range, jitter, tactile_keys, mode, cache_dir,
        out_of_range, seed, steps, contact_force, min_contact_area, batch_size, force_keys, background_keys,
        background_images, window_offsets, fps), by name.
    Online mode on other datasets than ours (or ours without labels) first reads every episode once
    (backgrounds, contact and reference forces computed as the cache writer does, kept for the workers).
    """

    def __init__(self, dataset, generator=None, *, estimator=None, build="now", progress=True, **settings):
        if settings.get("cache_dir") is not None:
            settings["cache_dir"] = str(settings["cache_dir"])
        self.config = ForceAugmentConfig(**settings)
        if not (hasattr(dataset, "__len__") and hasattr(dataset, "__getitem__")):
            raise ValueError(f"dataset: expected a map-style dataset (len and items by index), got {type(dataset).__name__}")
        self.dataset = dataset
        self.n_base = len(dataset)
        if self.n_base == 0:
            raise ValueError("dataset: is empty")
        probe = dataset[0]
        adapters.check_probe(probe)
        self.keys = resolve_keys(probe, self.config, dataset)
        self.tactile_keys = self.keys.tactile_keys
        if isinstance(estimator, (str, os.PathLike)):
            estimator = estimator_at(estimator)
        elif estimator is not None and not callable(getattr(estimator, "predict", None)):
            raise ValueError(f"estimator: expected a ForceEstimator, a checkpoint folder or a calibration bundle, got "
                             f"{type(estimator).__name__}")
        if isinstance(generator, (str, os.PathLike)) and estimator is None:
            estimator = bundle_estimator(generator)  # a calibration bundle brings its estimator; else None
        self.references = ReferenceForces(self.keys, self.config.contact_force, self.config.min_contact_area, estimator,
                                          self.config.estimated_reference)
        self.labelled = self.references.labelled
        self.progress = progress
        self._use_generator(generator)
        self._frames = None  # (episode, frame) per index, when known without reading items
        self._source, self._source_index = None, None  # EpisodeDataset read directly (cache mode)
        self.cache_dir, self._reader, self._online = None, None, None
        if self.config.mode == "online":
            self._online = OnlineGenerator(self.generator, self.config, self.steps, self.keys, self.references)
            per_item = self.config.target_range is None and adapters.episode_source(dataset)[0] is not None and all(
                self.labelled.values()) and all(
                self.keys.recorded(k) and self.keys.offsets[k] is None for k in self.tactile_keys)
            if not per_item:  # as the cache writer sees each episode (one background per episode, its estimates)
                self._online.tables = self._episode_tables()
            return
        if build not in BUILD:
            raise ValueError(f"build: expected one of {BUILD}, got {build!r}")
        settings = self.settings()
        self.cache_dir = Path(self.config.cache_dir) if self.config.cache_dir else self._default_cache_dir(settings)
        self._reader = ChunkReader(self.cache_dir, self.tactile_keys, ChunkSpec.of(settings))
        self._source, self._source_index = adapters.episode_source(dataset)
        if self._source is not None:
            self._frames = dataset.frame_table()
        check_manifest(self.cache_dir, settings)
        if build == "now":
            self.build_cache(progress=progress)
            self.wait_complete()
        if build != "manual":
            self._require_complete()

    # --- set-up ---------------------------------------------------------------------------------
    def _use_generator(self, generator) -> None:
        """Set ``generator`` (a ForceGenerator, a checkpoint folder or preset name; None: the default), its DDIM
        steps and numerics, refusing what the settings cannot run with before anything is written."""
        if generator is None or isinstance(generator, (str, os.PathLike)):
            from controltac_il.generator import ForceGenerator

            generator = ForceGenerator.from_pretrained(generator, pose_adapter="pose" if self.config.pose_offset else None)
        if not callable(getattr(generator, "generate_at", None)):
            raise ValueError(f"generator: expected a ForceGenerator, a checkpoint folder or a preset name, got "
                             f"{type(generator).__name__}")
        if self.config.pose_offset is not None and getattr(generator, "pose_adapter", None) is None:
            raise ValueError("pose_offset: needs a generator with the stage-2 pose adapter "
                             "(ForceGenerator.from_pretrained(pose_adapter='pose'))")
        steps = int(self.config.steps if self.config.steps is not None else generator.config.default_steps)
        most = generator.config.diffusion.num_train_timesteps
        if not 1 <= steps <= most:
            raise ValueError(f"steps: expected DDIM steps in [1, {most}] (the generator's training steps), got {steps}")
        self.generator, self.steps = generator, steps
        self.numerics = generator.numerics()  # as constructed: the thread count the frames are generated with

    @property
    def estimator(self):
        """The force estimator (loaded on first use); a clear error when it is not available."""
        return self.references.estimator

    def settings(self) -> dict:
        """Everything that decides the augmented frames (compared against a cache's manifest)."""
        cfg = asdict(self.config)
        for k in ("mode", "cache_dir", "batch_size", "window_offsets", "fps"):  # do not change the frames
            cfg.pop(k)
        for k in ("force_keys", "background_keys", "background_images"):  # recorded below, only where given
            cfg.pop(k)
        cfg["steps"] = self.steps
        cfg["tactile_keys"] = list(self.tactile_keys)
        cfg["generator_hash"] = str(self.generator.checkpoint_hash)
        cfg["numerics"] = self.numerics  # a cache built with another thread count is another cache
        for k in ("pose_offset", "target_range"):
            if cfg[k] is None:
                cfg.pop(k)  # off: caches built before the setting existed stay valid
        if "pose_offset" in cfg:
            cfg["pose_adapter_hash"] = str(self.generator.pose_adapter_hash)
        cfg["reference_force"] = {k: ("labels" if v else "estimator") for k, v in self.labelled.items()}
        cfg.update(self.keys.settings(self.config.force_keys is not None, self.config.background_keys is not None))
        if not all(self.labelled.values()):
            cfg["estimator_hash"] = str(getattr(self.estimator, "checkpoint_hash", None))
        else:
            cfg.pop("estimated_reference")  # labels only: caches built before the setting existed stay valid
        fp = getattr(self.dataset, "fingerprint", None)  # an EpisodeSubset's holds its indices' digest
        data = dict(fp()) if callable(fp) else {}
        data.pop("root", None)
        cfg["data"] = {"type": type(self.dataset).__name__, "length": self.n_base, **data}
        return json.loads(json.dumps(cfg))

    def _default_cache_dir(self, settings: dict) -> Path:
        named = {**settings, "cache_format": CACHE_FORMAT}  # a new format gets a new folder
        digest = hashlib.sha256(json.dumps(named, sort_keys=True).encode()).hexdigest()[:16]
        return cache_root() / "augment" / digest

    # --- size and indexing ----------------------------------------------------------------------
    def __len__(self) -> int:
        return (self.config.copies + 1) * self.n_base

    def __getitem__(self, index: int) -> dict:
        n = len(self)
        index = as_index(index, "ForceAugment")
        if not -n <= index < n:
            raise IndexError(f"index {index} out of range for {n} items")
        copy, base = divmod(int(index) % n, self.n_base)
        if copy and self._frames is not None:  # the project's dataset: do not read frames about to be replaced
            episode, frame = int(self._frames[0][base]), int(self._frames[1][base])
            outcome = self.chunk(episode, copy).frames.get(frame)
            regenerated = [k for k, o in zip(self.tactile_keys, outcome.keys) if o.row >= 0] if outcome else []
            src = base if self._source_index is None else int(self._source_index[base])
            return self._from_cache(self._source.item(src, skip_keys=regenerated), episode, copy, frame)
        item = dict(self.dataset[base])
        if copy == 0:
            real = FrameOutcome(0.0, 0.0, tuple(KeyOutcome(STATUS["real"]) for _ in self.tactile_keys))
            return self._annotate(item, 0, real)
        episode, frame = adapters.episode_frame(item)
        if self.config.mode == "cache":
            return self._from_cache(item, episode, copy, frame)
        item, outcome = self._online.item(item, episode, copy, frame)
        return self._annotate(item, copy, outcome)

    def chunk(self, episode: int, copy: int):
        """The opened and checked cache chunk of (episode, copy): ``frames`` {frame: FrameOutcome}, ``files``
        (one FrameFile per tactile key: ``read(row)``), ``records``."""
        if self._reader.frames is None:
            self._reader.frames = {e: [t for t, _ in rows] for e, rows in self._episodes().items()}
        return self._reader.chunk(episode, copy)

    def _from_cache(self, item: dict, episode: int, copy: int, frame: int) -> dict:
        """The cached images of every frame the item's tactile keys hold (its own, each unpadded window position)."""
        self.chunk(episode, copy)
        outcome, files = self._reader.frame(episode, copy, frame)
        for j, k in enumerate(self.tactile_keys):
            for p, f in self.keys.positions(item, k, frame):
                o = outcome.keys[j] if f == frame else self._reader.frame(episode, copy, f)[0].keys[j]
                if o.row >= 0:
                    adapters.put_image(item, k, files[j].read(o.row), p)
                    for q in self.keys.label_positions(item, k, frame, f):
                        adapters.put_force(item, self.keys.labels[k], o.target, q)
        return self._annotate(item, copy, outcome)

    def _annotate(self, item: dict, copy: int, outcome: FrameOutcome) -> dict:
        self.keys.put_images(item)
        labels = {k: self.keys.label(item, k) for k in self.tactile_keys}
        return annotate(item, copy, outcome, self.tactile_keys, labels)

    def info(self, item: dict) -> dict:
        """Named columns of ``item["augment"]`` (an item's (K, 10) or a batch's (B, K, 10)), for logging:
        copy, offset, jitter, augmented (any key regenerated), and per tactile key ``status.<key>``,
        ``reference_force.<key>`` (..., 3), ``target_force.<key>`` (..., 3)."""
        return info(item, self.tactile_keys)

    # --- episodes and chunks --------------------------------------------------------------------
    def _episodes(self) -> "OrderedDict[int, list[tuple[int, int]]]":
        """episode -> [(frame, dataset index)] sorted by frame (from ``frame_table()`` when the dataset has it)."""
        if getattr(self, "_episode_cache", None) is not None:
            return self._episode_cache
        columns = adapters.index_columns(self.dataset, self.n_base)
        if columns is not None:
            eps, frames = columns
        else:
            eps, frames = np.empty(self.n_base, np.int64), np.empty(self.n_base, np.int64)
            for i in tqdm(range(self.n_base), desc="scanning", disable=tty_only(self.progress), file=sys.stderr):
                eps[i], frames[i] = adapters.episode_frame(self.dataset[i])
        out: OrderedDict = OrderedDict()
        for i in np.lexsort((frames, eps)):
            rows = out.setdefault(int(eps[i]), [])
            if rows and rows[-1][0] == frames[i]:
                raise ValueError(f"dataset: episode {int(eps[i])} has frame_index {int(frames[i])} twice (items "
                                 f"{rows[-1][1]} and {int(i)}); episodes are told apart by episode_index alone")
            rows.append((int(frames[i]), int(i)))
        self._episode_cache = out
        return out

    def chunk_list(self) -> list[tuple[int, int]]:
        """Every (episode, copy) chunk of the cache, in build order."""
        return [(e, k) for e in self._episodes() for k in range(1, self.config.copies + 1)]

    def missing_chunks(self) -> list[tuple[int, int]]:
        return [c for c in self.chunk_list() if not chunk_done(self.cache_dir, *c)]

    def _load_episode(self, episode: int) -> EpisodeFrames:
        rows = self._episodes()[episode]
        items = [self.dataset[i] for _, i in rows]
        for (t, _), it in zip(rows, items):
            if adapters.episode_frame(it) != (episode, t):
                raise ValueError(f"dataset: item order changed while building (episode {episode}, frame {t})")
        return self.references.load_episode(items, self.tactile_keys, episode)

    def _episode_tables(self) -> EpisodeTables:
        """Online mode: every episode's backgrounds, contact and reference forces, as the cache writer has them."""
        tables = EpisodeTables.empty()
        for e, rows in tqdm(self._episodes().items(), desc="reading episodes", disable=tty_only(self.progress),
                            file=sys.stderr):
            tables.add(e, [t for t, _ in rows], self._load_episode(e))
        return tables

    def _writer(self) -> CacheWriter:
        return CacheWriter(self.cache_dir, self.generator, self.config, self.steps, self.tactile_keys,
                           self._episodes(), self._load_episode,
                           self._reader.spec if self._reader is not None else ChunkSpec.of(self.settings()))

    # --- cache mode: build ----------------------------------------------------------------------
    def prepare_cache(self) -> list[tuple[int, int]]:
        """Check the cache folder against these settings (the chunks already there refused unless they provably
        belong) or start it; returns ``chunk_list()``. ``build_cache`` runs it first unless given its result."""
        if self.config.mode != "cache":
            raise ValueError("build_cache: only in mode='cache'")
        settings = self.settings()
        self._reader.spec = ChunkSpec.of(settings)
        chunks = self.chunk_list()
        if check_manifest(self.cache_dir, settings, chunks):
            self.verify_cache()
        else:
            write_manifest(self.cache_dir, settings, chunks)
        remove_leftovers(self.cache_dir)
        return chunks

    def build_cache(self, rank: int | None = None, world_size: int | None = None, progress: bool = True,
                    stop_after: int | None = None, on_chunk=None, prepared: list | None = None) -> dict:
        """Generate this rank's missing chunks (rank/world_size default to torchrun's RANK/WORLD_SIZE).

        Chunk j of ``chunk_list()`` belongs to rank ``j * world_size // len(chunks)``; each chunk is
        written atomically, so an interrupted build resumes where it stopped and equals a clean one.
        stop_after: stop after writing this many chunks (to split a build). on_chunk: called with (episode, copy)
        after each chunk is written (an exception it raises stops the build). prepared: ``prepare_cache()``'s
        result where it ran already. Returns counts of the run.
        """
        rank = int(os.environ.get("RANK", 0)) if rank is None else int(rank)
        world_size = int(os.environ.get("WORLD_SIZE", 1)) if world_size is None else int(world_size)
        if not 0 <= rank < world_size:
            raise ValueError(f"rank: expected 0 <= rank < world_size={world_size}, got {rank}")
        chunks = self.prepare_cache() if prepared is None else prepared
        return self._writer().build(chunks, rank, world_size, progress, stop_after, on_chunk)

    def verify_cache(self) -> int:
        """Check every built chunk against the manifest's settings (``provenance.check_chunk``, image file
        shapes and sizes); StaleCacheError naming the first that does not provably belong. Returns the
        number of chunks checked."""
        done = [c for c in self.chunk_list() if chunk_done(self.cache_dir, *c)]
        for e, k in done:
            self.chunk(e, k)
        return len(done)

    def plan(self, progress: bool = False) -> list[dict]:
        """Provenance records of every augmented frame without generating (reads the whole dataset once).

        Lets a user count contact / clamped / skipped frames before building, or in online mode.
        """
        writer, out = self._writer(), []
        for e in tqdm(list(self._episodes()), desc="planning", disable=tty_only(progress), file=sys.stderr):
            ep = self._load_episode(e)
            for k in range(1, self.config.copies + 1):
                out.extend(r.to_json() for r in writer.plan_chunk(e, k, ep))
        return out

    def wait_complete(self, poll_s: float = 2.0) -> None:
        """Under torchrun, wait until the other ranks have written their chunks."""
        if int(os.environ.get("WORLD_SIZE", 1)) <= 1:
            return
        import torch.distributed as dist

        if dist.is_available() and dist.is_initialized():
            dist.barrier()
            return
        while self.missing_chunks():
            time.sleep(poll_s)

    def _require_complete(self) -> None:
        missing = self.missing_chunks()
        if missing:
            raise ValueError(f"cache {self.cache_dir}: {len(missing)} chunk(s) missing, e.g. episode {missing[0][0]} "
                             f"copy {missing[0][1]}; build it (python -m controltac_il.augment) or pass build='now'")
        check_manifest(self.cache_dir, self.settings(), self.chunk_list())
        self.verify_cache()

    # --- what was done --------------------------------------------------------------------------
    def provenance(self) -> list[dict]:
        """Every augmented frame's record (cache mode): episode, copy, frame, key, offset, jitter,
        reference and target force, status, generator hash, steps, noise seed, pose offset (None: not moved;
        chunks written before stage 2 existed have none)."""
        if self.config.mode != "cache":
            raise ValueError("provenance: only in mode='cache'")
        return [{"pose_offset": None, **r} for e, k in self.chunk_list() for r in self.chunk(e, k).records]

    def summary(self, copies: int | None = None) -> dict:
        """Counts over the augmented copies (the first ``copies`` of them; None: all): tactile frames, no_contact,
        regenerated, clamped, skipped.

        From the cache's provenance in cache mode; from ``plan()`` (one pass over the data) online.
        """
        if copies is not None and (not is_int(copies) or copies < 0):
            raise ValueError(f"copies: expected None or an int >= 0, got {copies!r}")
        recs = self.provenance() if self.config.mode == "cache" else self.plan()
        recs = [r for r in recs if copies is None or r["copy"] <= copies]
        counts = {name: 0 for name in ("no_contact", "regenerated", "clamped", "skipped")}
        for r in recs:
            counts[r["status"]] += 1
        total = len(recs)
        return {"tactile_frames": total, **counts,
                "fraction_regenerated": (counts["regenerated"] + counts["clamped"]) / total if total else 0.0}
