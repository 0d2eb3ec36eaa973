"""The draws of a virtual trajectory, pure functions of (seed, episode, copy, frame), and its target force."""

from __future__ import annotations

import numpy as np

from controltac_il.augment.records import STATUS
from controltac_il.tactile.pose import move_mask
from controltac_il.tactile.residual import contact_mask


def _stream(seed: int, *key: int) -> np.random.Generator:
    return np.random.Generator(np.random.Philox(np.random.SeedSequence(seed, spawn_key=key)))


def copy_offset(seed: int, episode: int, copy: int, offset_range: tuple[float, float]) -> float:
    """Normal-force offset (N) of copy ``copy`` of episode ``episode``: U[offset_range]."""
    return float(_stream(seed, episode, copy, 0).uniform(*offset_range))


def copy_pose_offset(seed: int, episode: int, copy: int, pose_offset) -> tuple[float, float, float] | None:
    """Rigid contact move (dx_px, dy_px, dtheta rad) of one copy: U[±max] per component of ``pose_offset`` =
    (max_dx_px, max_dy_px, max_dtheta_deg); None when pose augmentation is off."""
    if pose_offset is None:
        return None
    u = _stream(seed, episode, copy, 3).uniform(-1.0, 1.0, 3) * np.asarray(pose_offset, np.float64)
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
    return float(jitter[int(_stream(seed, episode, copy, 1, frame).integers(len(jitter)))])


def noise_seed(seed: int, episode: int, copy: int, frame: int, key_index: int) -> int:
    """Generator noise seed of one tactile image of one frame of a copy (63-bit int)."""
    return int(np.random.SeedSequence(seed, spawn_key=(episode, copy, 2, frame, key_index)).generate_state(1, np.uint64)[0] >> 1)


def requested_target(reference, delta_fz: float) -> np.ndarray:
    """The target force (3,) N asked of the generator: reference + (0, 0, offset + jitter). Not clamped:
    the generator decides what to do with a target outside its validated range."""
    return np.asarray(reference, np.float64) + np.array([0.0, 0.0, delta_fz])


def status_of(decision, i: int) -> int:
    """STATUS code of sample ``i`` of a generator ``TargetDecision``."""
    if decision.skipped[i]:
        return STATUS["skipped"]
    return STATUS["clamped"] if decision.clamped[i] else STATUS["regenerated"]
