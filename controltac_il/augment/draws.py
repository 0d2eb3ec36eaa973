"""The plan of a virtual trajectory: every draw a pure function of (seed, episode, copy, frame), and what one
tactile frame asks of the generator (:func:`plan_frame`, the one place both the cache writer and online mode
take it from)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controltac_il.augment.records import STATUS
from controltac_il.tactile.pose import move_mask
from controltac_il.tactile.residual import contact_mask


def draw_stream(seed: int, *key: int) -> np.random.Generator:
    return np.random.Generator(np.random.Philox(np.random.SeedSequence(seed, spawn_key=key)))


def copy_offset(seed: int, episode: int, copy: int, offset_range: tuple[float, float],
                target_range: tuple[float, float] | None = None, episode_fz: float | None = None) -> float:
    """Normal-force offset (N) of copy ``copy`` of episode ``episode``: U[offset_range]; with ``target_range``,
    U[target_range] - ``episode_fz`` (the episode's median contact Fz, N; 0 offset when it has no contact)."""
    if target_range is None:
        return float(draw_stream(seed, episode, copy, 0).uniform(*offset_range))
    if episode_fz is None:
        return 0.0
    return float(draw_stream(seed, episode, copy, 0).uniform(*target_range)) - float(episode_fz)


def episode_contact_fz(contact: dict, reference: dict) -> float | None:
    """Median Fz (N) of an episode's contact frames over every tactile key: ``contact`` {key: bool (T,)},
    ``reference`` {key: (T, 3) N}; None without a contact frame with a known force."""
    fz = np.concatenate([np.asarray(reference[k], np.float64)[np.asarray(contact[k], bool), 2] for k in contact])
    fz = fz[np.isfinite(fz)]
    return float(np.median(fz)) if fz.size else None


def copy_pose_offset(seed: int, episode: int, copy: int, pose_offset) -> tuple[float, float, float] | None:
    """Rigid contact move (dx_px, dy_px, dtheta rad) of one copy: U[±max] per component of ``pose_offset`` =
    (max_dx_px, max_dy_px, max_dtheta_deg); None when pose augmentation is off."""
    if pose_offset is None:
        return None
    u = draw_stream(seed, episode, copy, 3).uniform(-1.0, 1.0, 3) * np.asarray(pose_offset, np.float64)
    return float(u[0]), float(u[1]), float(np.radians(u[2]))


def moved_contact(residual: np.ndarray, move) -> np.ndarray | None:
    """The frame's contact pixels (``contact_mask``) moved by ``move``: the stage-2 mask, bool (H, W); None when
    there is no move, no contact pixel, or the move leaves none on the pad (the force change alone applies)."""
    mask = None if move is None else contact_mask(residual)
    if mask is None or not mask.any():
        return None
    try:
        return move_mask(mask, move)
    except ValueError:
        return None


def frame_jitter(seed: int, episode: int, copy: int, frame: int, jitter: tuple[float, ...]) -> float:
    """Jitter (N) of one frame of a copy: uniform over the ``jitter`` values."""
    return float(jitter[int(draw_stream(seed, episode, copy, 1, frame).integers(len(jitter)))])


def noise_seed(seed: int, episode: int, copy: int, frame: int, key_index: int) -> int:
    """Generator noise seed of one tactile image of one frame of a copy (63-bit int)."""
    return int(np.random.SeedSequence(seed, spawn_key=(episode, copy, 2, frame, key_index)).generate_state(1, np.uint64)[0] >> 1)


def requested_target(reference, delta_fz: float) -> np.ndarray:
    """The target force (3,) N asked of the generator: reference + (0, 0, offset + jitter). Not clamped:
    the generator decides what to do with a target outside its validated range."""
    return np.asarray(reference, np.float64) + np.array([0.0, 0.0, delta_fz])


# A reference force the generator was not validated on cannot be moved: both modes keep such a frame real.
REFERENCE_OUT_OF_RANGE = "skip"


@dataclass(frozen=True)
class FramePlan:
    """What one tactile frame (key ``key_index``) of copy ``copy`` asks of the generator.

    offset: the copy's normal-force offset (N); jitter: the frame's jitter (N); target: the requested target
    force (3,) N = reference + (0, 0, offset + jitter), None without a reference (no contact); noise_seed: the
    generator's noise seed for this image; move: the copy's rigid contact move (dx_px, dy_px, dθ rad) or None."""

    offset: float
    jitter: float
    target: np.ndarray | None
    noise_seed: int
    move: tuple[float, float, float] | None


def plan_frame(config, episode: int, copy: int, frame: int, key_index: int, reference=None,
               episode_fz: float | None = None) -> FramePlan:
    """The :class:`FramePlan` of one tactile frame under ``config`` (a ForceAugmentConfig); ``reference``: the
    frame's reference force (3,) N, None when it is not in contact; ``episode_fz``: the episode's median contact
    Fz (``episode_contact_fz``), used only with ``config.target_range``."""
    offset = copy_offset(config.seed, episode, copy, config.offset_range, config.target_range, episode_fz)
    jitter = frame_jitter(config.seed, episode, copy, frame, config.jitter)
    target = None if reference is None else requested_target(reference, offset + jitter)
    return FramePlan(offset, jitter, target, noise_seed(config.seed, episode, copy, frame, key_index),
                     copy_pose_offset(config.seed, episode, copy, config.pose_offset))


def status_of(decision, i: int) -> int:
    """STATUS code of sample ``i`` of a generator ``TargetDecision``."""
    if decision.skipped[i]:
        return STATUS["skipped"]
    return STATUS["clamped"] if decision.clamped[i] else STATUS["regenerated"]
