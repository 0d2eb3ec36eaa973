"""The generator's validated force range, and what it does with a target outside it (the only place that decides).

The paper validates stage 1 for target forces Fz in [1, 10] N and |Fx|, |Fy| <= 1 N. ``VALIDATED_RANGE``
is that range; ``decide_targets`` is the one function that clamps, skips or refuses a requested target
force, and ``ForceGenerator`` applies it to every sample it generates. Callers pass the reference force
and the target force they want and receive a ``TargetDecision`` saying what was done. A reference force
outside the range is refused (or, under "skip", its sample skipped): the model never saw one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RANGE_POLICIES = ("clamp", "skip", "error")
REFERENCE_POLICIES = ("error", "skip")  # a reference force cannot be clamped: its image shows that force


@dataclass(frozen=True)
class ForceRange:
    """A box of forces [Fx, Fy, Fz] in N: Fz in ``fz``, |Fx|, |Fy| <= ``shear_max``.

    tolerance: N by which a target may lie beyond a bound and still count as inside (float32 round
        trips of in-range values are not out of range).
    """

    fz: tuple[float, float] = (1.0, 10.0)
    shear_max: float = 1.0
    tolerance: float = 1e-6

    def __post_init__(self):
        lo, hi = self.fz
        if not (np.isfinite([lo, hi, self.shear_max, self.tolerance]).all() and lo < hi
                and self.shear_max >= 0 and self.tolerance >= 0):
            raise ValueError(f"ForceRange: fz must be finite (low, high) with low < high and shear_max, tolerance "
                             f"finite and >= 0, got fz={self.fz}, shear_max={self.shear_max}, tolerance={self.tolerance}")

    @property
    def low(self) -> np.ndarray:
        return np.array([-self.shear_max, -self.shear_max, self.fz[0]], np.float64)

    @property
    def high(self) -> np.ndarray:
        return np.array([self.shear_max, self.shear_max, self.fz[1]], np.float64)

    @property
    def span(self) -> np.ndarray:
        """Largest |ΔF| between two forces of the range, per component (N)."""
        return self.high - self.low

    def outside(self, force) -> np.ndarray:
        """bool (..., 3): components of ``force`` (..., 3) beyond the range (by more than the tolerance); a NaN
        component is outside too (no force the model was validated on)."""
        f = np.asarray(force, np.float64)
        return ~((f >= self.low - self.tolerance) & (f <= self.high + self.tolerance))

    def clamp(self, force) -> np.ndarray:
        return np.clip(np.asarray(force, np.float64), self.low, self.high)

    def delta_range(self) -> "ForceRange":
        """The box of ΔF between two forces of this range: |ΔFx|, |ΔFy| <= 2 shear_max, |ΔFz| <= the Fz span."""
        s = self.fz[1] - self.fz[0]
        return ForceRange(fz=(-s, s), shear_max=2 * self.shear_max, tolerance=self.tolerance)

    def describe(self) -> str:
        return f"Fz in [{self.fz[0]:g}, {self.fz[1]:g}] N, |Fx|, |Fy| <= {self.shear_max:g} N"

    def card(self) -> dict:
        """The range as recorded in a checkpoint's model card."""
        return {"fz_n": [float(self.fz[0]), float(self.fz[1])], "abs_shear_n": float(self.shear_max)}


VALIDATED_RANGE = ForceRange()
NOMINAL_FZ = sum(VALIDATED_RANGE.fz) / 2  # N, 5.5: the range's middle, the working reference of an untrusted estimate


@dataclass(frozen=True)
class TargetDecision:
    """What the generator does with each requested target of a batch.

    requested: (B, 3) N, the target forces asked for. target: (B, 3) N, the force each generated sample
    shows (the requested one, or clamped into range; for a skipped sample the requested one, not
    generated). clamped, skipped: bool (B,). reference_outside: bool (B,), samples whose reference
    force lies outside the range (skipped: a reference cannot be moved; None when no reference was given).
    """

    requested: np.ndarray
    target: np.ndarray
    clamped: np.ndarray
    skipped: np.ndarray
    reference_outside: np.ndarray | None = None

    @property
    def generated(self) -> np.ndarray:
        """bool (B,): samples the generator draws (not skipped)."""
        return ~self.skipped


def decide_targets(target_force, out_of_range: str = "clamp", force_range: ForceRange = VALIDATED_RANGE,
                   what: str = "target force", reference_force=None,
                   reference_out_of_range: str | None = None) -> TargetDecision:
    """Apply ``out_of_range`` to requested targets (B, 3) N, finite: "clamp" moves a target outside the range into
    it, "skip" leaves it ungenerated, "error" raises ValueError. Nothing else clamps a target.

    reference_force: optional (B, 3) N, the force each reference image shows. The generator was validated
    only on references inside ``VALIDATED_RANGE``, and a reference cannot be moved (its image shows that
    force), so a reference outside it is refused (ValueError) or its sample skipped (``reference_outside``
    says which), as ``reference_out_of_range`` says: "error" or "skip"; None = "skip" under
    out_of_range="skip", else "error"."""
    if out_of_range not in RANGE_POLICIES:
        raise ValueError(f"out_of_range must be one of {RANGE_POLICIES}, got {out_of_range!r}")
    if reference_out_of_range is None:
        reference_out_of_range = "skip" if out_of_range == "skip" else "error"
    if reference_out_of_range not in REFERENCE_POLICIES:
        raise ValueError(f"reference_out_of_range must be one of {REFERENCE_POLICIES} or None, "
                         f"got {reference_out_of_range!r}")
    requested = np.asarray(target_force, np.float64)
    if requested.ndim != 2 or requested.shape[1] != 3:
        raise ValueError(f"{what} must have shape (B, 3) [Fx, Fy, Fz] N, got {requested.shape}")
    if not np.isfinite(requested).all():  # no range decision makes NaN a force: clamping would keep it
        raise ValueError(f"{what} holds NaN or inf (index {int(np.flatnonzero(~np.isfinite(requested).all(1))[0])})")
    ref_out = None
    if reference_force is not None:
        ref = np.asarray(reference_force, np.float64)
        if ref.shape != requested.shape:
            raise ValueError(f"reference_force must have the {what}'s shape {requested.shape}, got {ref.shape}")
        ref_out = VALIDATED_RANGE.outside(ref).any(axis=-1)
        if ref_out.any() and reference_out_of_range == "error":
            first = int(np.flatnonzero(ref_out)[0])
            raise ValueError(
                f"reference_force: {int(ref_out.sum())} of {len(ref_out)} samples lie outside the validated range "
                f"({VALIDATED_RANGE.describe()}), e.g. index {first}: {np.round(ref[first], 4).tolist()} N; the "
                "generator was not validated on such references and cannot move them (the image shows that "
                "force): pass out_of_range='skip' (or reference_out_of_range='skip') to keep those samples unchanged")
    bad = force_range.outside(requested).any(axis=-1)
    if bad.any() and out_of_range == "error":
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{int(bad.sum())} of {len(bad)} samples have a {what} outside the validated range "
            f"({force_range.describe()}), e.g. index {first}; pass out_of_range='clamp' to move them into range")
    clamped = bad if out_of_range == "clamp" else np.zeros_like(bad)
    skipped = bad if out_of_range == "skip" else np.zeros_like(bad)
    if ref_out is not None:  # not generated at all: neither clamped nor counted twice
        skipped, clamped = skipped | ref_out, clamped & ~ref_out
    target = np.where(clamped[:, None], force_range.clamp(requested), requested)
    return TargetDecision(requested=requested, target=target, clamped=clamped, skipped=skipped,
                          reference_outside=ref_out)
