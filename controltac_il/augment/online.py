"""Online mode: the tactile images of one item of an augmented copy, generated on access.

Every frame a tactile key holds (the item's own, or each unpadded position of a time window) is generated
as that frame alone would be: with the copy's offset, that frame's jitter and noise seed. Where the items
carry no background, no force label, or windows, each episode's backgrounds, contact and reference forces
are computed once at set-up exactly as the cache writer computes them (``EpisodeTables``), so both modes
ask the generator the same questions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.draws import (REFERENCE_OUT_OF_RANGE, episode_contact_fz, moved_contact, plan_frame,
                                        status_of)
from controltac_il.augment.items import put_force, put_image, to_hwc_uint8
from controltac_il.augment.keys import KeyMap
from controltac_il.augment.records import STATUS, FrameOutcome, KeyOutcome
from controltac_il.augment.reference import EpisodeFrames, ReferenceForces
from controltac_il.tactile.residual import from_residual, to_residual


@dataclass
class EpisodeTables:
    """Per episode: frame -> position, and per (episode, key) the background, contact (T,) and reference
    force (T, 3) of ``ReferenceForces.load_episode`` (residuals dropped)."""

    positions: dict
    backgrounds: dict
    contact: dict
    reference: dict

    @classmethod
    def empty(cls) -> "EpisodeTables":
        return cls({}, {}, {}, {})

    def add(self, episode: int, frames: list[int], ep: EpisodeFrames) -> None:
        self.positions[episode] = {t: i for i, t in enumerate(frames)}
        for k in ep.backgrounds:
            self.backgrounds[episode, k] = ep.backgrounds[k]
            self.contact[episode, k], self.reference[episode, k] = ep.contact[k], ep.reference[k]

    def contact_fz(self, episode: int) -> float | None:
        """The episode's median contact Fz (N) over every key (``draws.episode_contact_fz``)."""
        keys = [k for e, k in self.contact if e == episode]
        return episode_contact_fz({k: self.contact[episode, k] for k in keys},
                                  {k: self.reference[episode, k] for k in keys})

    def of(self, episode: int, key: str, frame: int) -> tuple[np.ndarray, bool, np.ndarray]:
        """(background, in contact, reference force) of one frame; ValueError for a frame not in the dataset."""
        i = self.positions.get(episode, {}).get(frame)
        if i is None:
            raise ValueError(f"dataset: episode {episode} has no frame {frame} (asked for by a window of {key!r})")
        return self.backgrounds[episode, key], bool(self.contact[episode, key][i]), self.reference[episode, key][i]


@dataclass
class OnlineGenerator:
    """What online generation needs: the generator and settings, the item keys, reference forces, and the
    episode tables (None: every item carries its background and labels, single frames)."""

    generator: object
    config: ForceAugmentConfig
    steps: int
    keys: KeyMap
    references: ReferenceForces
    tables: EpisodeTables | None = None

    def item(self, item: dict, episode: int, copy: int, frame: int) -> tuple[dict, FrameOutcome]:
        """Replace the frames of ``item`` (frame ``frame`` of copy ``copy`` of ``episode``) that the generator
        redraws; returns the item and what was done to its own frame per key."""
        own = []
        for j, k in enumerate(self.keys.tactile_keys):
            mine = None
            for p, f in self.keys.positions(item, k, frame):
                image = to_hwc_uint8(item[k] if p is None else item[k][p], k)
                outcome, new = self.frame(item, image, episode, copy, f, j)
                if new is not None:
                    put_image(item, k, new, p)
                    for q in self.keys.label_positions(item, k, frame, f):
                        put_force(item, self.keys.labels[k], outcome.target, q)
                if f == frame:
                    mine = outcome
            own.append(mine)
        plan = plan_frame(self.config, episode, copy, frame, 0, episode_fz=self._fz(episode))
        return item, FrameOutcome(plan.offset, plan.jitter, tuple(own))

    def _fz(self, episode: int) -> float | None:
        """The episode's median contact Fz when the offset depends on it (``target_range``; tables are built)."""
        return self.tables.contact_fz(episode) if self.config.target_range is not None else None

    def frame(self, item: dict, image: np.ndarray, episode: int, copy: int, frame: int, j: int
              ) -> tuple[KeyOutcome, np.ndarray | None]:
        """One frame of tactile key ``j``: its outcome and the generated image (None: keep the real one)."""
        cfg, k = self.config, self.keys.tactile_keys[j]
        if self.tables is not None:
            background, touch, ref = self.tables.of(episode, k, frame)
            residual = to_residual(image, background)
            ref = ref if touch else None
        else:
            background = self.keys.background(item, k)
            residual = to_residual(image, background)
            ref = self.references.of_frame(image, residual, self.references.label(item, k))
        if ref is None:
            return KeyOutcome(STATUS["no_contact"]), None
        plan = plan_frame(cfg, episode, copy, frame, j, ref, self._fz(episode))
        mask = moved_contact(residual, plan.move)
        res = self.generator.generate_at(residual[None], ref[None], plan.target[None],
                                         steps=self.steps, seed=[plan.noise_seed],
                                         batch_size=cfg.batch_size, out_of_range=cfg.out_of_range,
                                         reference_out_of_range=REFERENCE_OUT_OF_RANGE,
                                         **({} if mask is None else {"mask": mask}))
        target, status = res.decision.target[0], status_of(res.decision, 0)
        outcome = KeyOutcome(status, reference=ref, target=target)
        if status == STATUS["skipped"]:
            return outcome, None
        return outcome, from_residual(res.residuals[0], background)
