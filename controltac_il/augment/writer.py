"""Building the cache: each (episode, copy) chunk planned, generated in one generator call and written
atomically with its provenance; chunks shared out among ranks (torchrun) and resumed where a build stopped.

A chunk is written into a temporary folder beside it and renamed into place (``controltac_il.io``), so a
build killed at any point leaves whole chunks and, at worst, a temporary folder that the next build
removes. Frames whose reference force lies outside the generator's validated range are not regenerated
(the generator skips them, ``reference_out_of_range="skip"``): kept real and recorded as skipped."""

from __future__ import annotations

import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm
from controltac_il.cli import tty_only

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.draws import (REFERENCE_OUT_OF_RANGE, episode_contact_fz, moved_contact, plan_frame,
                                        status_of)
from controltac_il.augment.provenance import ChunkSpec, FrameRecord, chunk_dir, chunk_done, provenance_text
from controltac_il.augment.records import STATUS_NAME
from controltac_il.augment.reference import EpisodeFrames
from controltac_il.generator.forces import TargetDecision
from controltac_il.io import atomic_dir, remove_leftovers
from controltac_il.tactile.residual import from_residual


class CacheWriter:
    """Writes chunks of ``cache_dir``. episodes: episode -> [(frame, dataset index)] sorted by frame;
    load_episode: episode -> EpisodeFrames; spec: what each chunk records of the cache's settings."""

    def __init__(self, cache_dir: Path, generator, config: ForceAugmentConfig, steps: int, tactile_keys,
                 episodes: dict, load_episode: Callable[[int], EpisodeFrames], spec: ChunkSpec):
        self.cache_dir, self.generator, self.config, self.steps = cache_dir, generator, config, steps
        self.tactile_keys, self.episodes, self.load_episode = tuple(tactile_keys), episodes, load_episode
        self.spec = spec

    def draft(self, episode: int, copy: int, ep: EpisodeFrames) -> tuple[list[FrameRecord], list[int]]:
        """Records of one chunk (every tactile key x frame) with the requested target of each frame in
        contact, and the positions of those records (what the generator is asked for)."""
        records, asked = [], []
        fz = episode_contact_fz(ep.contact, ep.reference)
        for j, k in enumerate(self.tactile_keys):
            for i, (t, _) in enumerate(self.episodes[episode]):
                ref = ep.reference[k][i] if ep.contact[k][i] else None
                plan = plan_frame(self.config, episode, copy, t, j, ref, fz)
                rec = FrameRecord(episode, copy, t, k, plan.offset, plan.jitter, None, None, "no_contact", -1, None,
                                  str(self.generator.checkpoint_hash), self.steps, ep.background_source[k])
                if ref is not None:
                    rec.reference_force, rec.target_force = ref.tolist(), plan.target.tolist()
                    rec.noise_seed = plan.noise_seed
                    asked.append(len(records))
                records.append(rec)
        return records, asked

    @staticmethod
    def settle(records: list[FrameRecord], asked: list[int], decision) -> list[FrameRecord]:
        """Fill in what the generator did (its ``TargetDecision`` for the ``asked`` records): status, target
        force used, and the row of each generated image in its key's file."""
        rows: dict[str, int] = {}
        for n, i in enumerate(asked):
            rec = records[i]
            rec.status = STATUS_NAME[status_of(decision, n)]
            rec.target_force = decision.target[n].tolist()
            if decision.skipped[n]:
                rec.noise_seed = None
            else:
                rec.row = rows.get(rec.key, 0)
                rows[rec.key] = rec.row + 1
        return records

    def pose_masks(self, episode: int, copy: int, residuals: np.ndarray) -> tuple[tuple | None, list]:
        """The copy's rigid move and, per residual, its moved contact mask (None: the force change alone)."""
        move = plan_frame(self.config, episode, copy, 0, 0).move
        return move, [moved_contact(r, move) for r in residuals]

    @staticmethod
    def record_moves(todo: list[FrameRecord], move, masks: list) -> None:
        for r, m in zip(todo, masks):
            r.pose_offset = list(move) if m is not None and r.row >= 0 else None

    def _asked(self, episode: int, records: list[FrameRecord], asked: list[int], ep: EpisodeFrames):
        """The asked records, their reference residuals (n, H, W, 3), reference and requested target forces (n, 3) N."""
        position = {t: i for i, (t, _) in enumerate(self.episodes[episode])}
        todo = [records[i] for i in asked]
        residuals = np.stack([ep.residuals[r.key][position[r.frame]] for r in todo]) if todo else None
        refs = np.asarray([r.reference_force for r in todo], np.float64).reshape(-1, 3)
        return todo, residuals, refs, np.asarray([r.target_force for r in todo], np.float64).reshape(-1, 3)

    def plan_chunk(self, episode: int, copy: int, ep: EpisodeFrames) -> list[FrameRecord]:
        """Records of one chunk as the generator would settle them, without generating (its range decision,
        ``resolve_targets``, is the one ``generate_at`` applies)."""
        records, asked = self.draft(episode, copy, ep)
        todo, residuals, refs, targets = self._asked(episode, records, asked, ep)
        self.settle(records, asked, self.generator.resolve_targets(
            targets, self.config.out_of_range, reference_force=refs, reference_out_of_range=REFERENCE_OUT_OF_RANGE))
        if self.config.pose_offset is not None and todo:
            self.record_moves(todo, *self.pose_masks(episode, copy, residuals))
        return records

    def write_chunk(self, episode: int, copy: int, ep: EpisodeFrames) -> int:
        """Generate and write one chunk atomically; returns the number of generated images."""
        records, asked = self.draft(episode, copy, ep)
        out = None
        if asked:  # every key of the chunk in one generator call (two with stage 2: frames moved and not)
            todo, residuals, refs, targets = self._asked(episode, records, asked, ep)
            move, masks = self.pose_masks(episode, copy, residuals)
            moved = np.array([m is not None for m in masks], bool)
            seeds = np.asarray([r.noise_seed for r in todo])
            out, decisions = np.empty_like(residuals), []
            for rows, extra in ((moved, {"mask": [m for m in masks if m is not None]}), (~moved, {})):
                if rows.any():
                    res = self.generator.generate_at(
                        residuals[rows], refs[rows], targets[rows], steps=self.steps, seed=seeds[rows].tolist(),
                        batch_size=self.config.batch_size, out_of_range=self.config.out_of_range,
                        reference_out_of_range=REFERENCE_OUT_OF_RANGE, **{k: np.stack(v) for k, v in extra.items()})
                    out[rows] = res.residuals
                    decisions.append((rows, res.decision))
            self.settle(records, asked, _merged(decisions, len(todo)))
            self.record_moves(todo, move, masks)
        with atomic_dir(chunk_dir(self.cache_dir, episode, copy)) as tmp:
            for j, k in enumerate(self.tactile_keys):
                mine = [n for n, i in enumerate(asked) if records[i].key == k and records[i].row >= 0]
                h, w = ep.residuals[k].shape[1:3]
                images = from_residual(out[mine], ep.backgrounds[k]) if mine else np.empty((0, h, w, 3), np.uint8)
                np.save(tmp / f"tactile_{j}.npy", images)
            (tmp / "provenance.json").write_text(provenance_text(episode, copy, records, self.spec))
        return sum(r.row >= 0 for r in records)

    def build(self, chunks: list[tuple[int, int]], rank: int, world_size: int, progress: bool,
              stop_after: int | None, on_chunk: Callable[[int, int], None] | None = None) -> dict:
        """Write this rank's missing chunks (chunk j belongs to rank j * world_size // len(chunks)); on_chunk:
        called with (episode, copy) after each is written."""
        remove_leftovers(self.cache_dir / "chunks")  # of a killed build, even when no chunk is left to write
        mine = [c for j, c in enumerate(chunks) if j * world_size // max(len(chunks), 1) == rank]
        todo = [c for c in mine if not chunk_done(self.cache_dir, *c)]
        if stop_after is not None:
            todo = todo[:stop_after]
        lengths = {e: len(v) for e, v in self.episodes.items()}
        counts = {"chunks": 0, "frames": 0, "generated": 0, "seconds": 0.0}
        t0 = time.perf_counter()
        bar = tqdm(total=sum(lengths[e] for e, _ in todo), unit="frame", desc=f"ForceAugment cache (rank {rank})",
                   disable=tty_only(progress), file=sys.stderr)
        for e, frames in self._read_ahead(list(dict.fromkeys(e for e, _ in todo))):
            for k in [k for d, k in todo if d == e]:
                counts["generated"] += self.write_chunk(e, k, frames)
                counts["chunks"] += 1
                counts["frames"] += lengths[e]
                bar.update(lengths[e])
                if on_chunk is not None:
                    on_chunk(e, k)
        bar.close()
        counts["seconds"] = time.perf_counter() - t0
        return counts

    def _read_ahead(self, episodes: list[int]):
        """(episode, its EpisodeFrames) in order, the next episode read by a thread while this one is generated."""
        with ThreadPoolExecutor(max_workers=1) as reader:
            ahead = reader.submit(self.load_episode, episodes[0]) if episodes else None
            for n, e in enumerate(episodes):
                frames = ahead.result()
                ahead = reader.submit(self.load_episode, episodes[n + 1]) if n + 1 < len(episodes) else None
                yield e, frames


def _merged(parts: list[tuple[np.ndarray, TargetDecision]], n: int) -> TargetDecision:
    """One TargetDecision (n samples) from the decisions ``generate_at`` returned for the rows (bool (n,)) it was
    called on."""
    out = TargetDecision(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, bool), np.zeros(n, bool))
    for rows, d in parts:
        out.requested[rows], out.target[rows] = d.requested, d.target
        out.clamped[rows], out.skipped[rows] = d.clamped, d.skipped
    return out
