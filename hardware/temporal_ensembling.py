"""ACT temporal ensembling: every chunk predicted so far votes for the action at step t.

A chunk predicted from the observation at step ``t0`` holds actions for steps ``t0 .. t0+len-1``.
The action at step ``t`` is the weighted mean of the chunks that cover ``t``, ordered oldest
first, with weights ``w_i = exp(-k * i)`` (``i = 0`` is the OLDEST prediction, as in ACT's
``all_time_actions`` with ``k = 0.01``), normalised to sum to one. An angle (``angle_dims``, e.g. yaw) votes
unwrapped to within pi of the oldest vote, so 3.13 and -3.13 rad (one heading) blend near pi, not to 0; votes that
need no unwrapping blend exactly as numbers.
"""

from __future__ import annotations

import bisect
import threading

import numpy as np

from controltac_il.config import is_int, is_real


def _check_step(t) -> None:
    """A control step is an int: a float one would be truncated, or index a chunk with a fraction."""
    if not is_int(t):
        raise ValueError(f"t must be an int control step, got {t!r}")


class TemporalEnsembler:
    """Collect action chunks by the step they were predicted for and blend them per step.

    chunk_size: largest chunk length accepted (ACT's N_a, 20 in the paper).
    action_dim: width A of an action vector.
    k: decay of the weights exp(-k * i) from the oldest prediction (0.01 in ACT); k >= 0.
    angle_dims: the action entries that are angles in radians, blended as headings (see the module docstring).
    Thread-safe: a policy thread may call :meth:`add_chunk` while the control loop calls :meth:`action`.
    """

    def __init__(self, chunk_size: int, action_dim: int, k: float = 0.01, angle_dims: tuple[int, ...] = ()):
        for name, value in (("chunk_size", chunk_size), ("action_dim", action_dim)):
            if not is_int(value) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not is_real(k) or k < 0:
            raise ValueError(f"k must be a finite number >= 0, got {k!r}")
        if not isinstance(angle_dims, (tuple, list)) or not all(is_int(d) and 0 <= d < action_dim for d in angle_dims):
            raise ValueError(f"angle_dims must be action entries in [0, {action_dim}), got {angle_dims!r}")
        self.chunk_size, self.action_dim, self.k = int(chunk_size), int(action_dim), float(k)
        self.angle_dims = tuple(int(d) for d in angle_dims)
        self._starts: list[int] = []  # sorted t0 of the chunks kept
        self._chunks: list[np.ndarray] = []
        self._lock = threading.Lock()

    def add_chunk(self, t: int, chunk: np.ndarray) -> None:
        """Add the chunk (L, action_dim), 1 <= L <= chunk_size, predicted from the observation at step ``t``."""
        _check_step(t)
        chunk = np.asarray(chunk, dtype=np.float64)
        if chunk.ndim != 2 or chunk.shape[1] != self.action_dim or not 1 <= chunk.shape[0] <= self.chunk_size:
            raise ValueError(
                f"chunk must have shape (L, {self.action_dim}) with 1 <= L <= {self.chunk_size}, got {chunk.shape}"
            )
        if not np.isfinite(chunk).all():
            raise ValueError(f"chunk for step {t} contains NaN or inf")
        with self._lock:
            i = bisect.bisect_right(self._starts, int(t))
            self._starts.insert(i, int(t))
            self._chunks.insert(i, chunk.copy())

    def covers(self, t: int) -> bool:
        """True when at least one chunk holds an action for step ``t``."""
        _check_step(t)
        with self._lock:
            return any(s <= t < s + len(c) for s, c in zip(self._starts, self._chunks))

    def action(self, t: int) -> np.ndarray:
        """Blended action (action_dim,) float64 for step ``t``; drops chunks that end before ``t``.

        Raises LookupError when no chunk covers ``t`` (the policy is late).
        """
        _check_step(t)
        with self._lock:
            keep = [i for i, (s, c) in enumerate(zip(self._starts, self._chunks)) if s + len(c) > t]
            self._starts = [self._starts[i] for i in keep]
            self._chunks = [self._chunks[i] for i in keep]
            votes = [c[t - s] for s, c in zip(self._starts, self._chunks) if s <= t]
        if not votes:
            raise LookupError(f"no predicted chunk covers step {t}")
        with np.errstate(over="ignore"):  # k * i past float range is -inf: its weight exp(-inf) is exactly 0
            w = np.exp(-self.k * np.arange(len(votes)))
        votes = np.stack(votes)
        for d in self.angle_dims:  # each vote the nearest equivalent of itself to the oldest one
            votes[:, d] -= 2 * np.pi * np.round((votes[:, d] - votes[0, d]) / (2 * np.pi))
        return (w / w.sum()) @ votes

    def reset(self) -> None:
        """Forget every chunk (start of an episode)."""
        with self._lock:
            self._starts.clear()
            self._chunks.clear()

    def __len__(self) -> int:
        with self._lock:
            return len(self._chunks)
