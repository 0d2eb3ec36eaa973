"""Configuration of the force estimator (model shape, input normalisation, force units)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class EstimatorConfig:
    """Shape and normalisation of a :class:`~controltac_il.estimators.model.ForceCNN`.

    Fields:
        input_height, input_width: pixel size the network sees; residuals of any other size are
            resized to it (area-averaged when shrinking), so one checkpoint reads 240x320 GelSight
            frames and the generator's 128x160 frames alike (same physical pad).
        widths: output channels of the stride-2 stages, one entry per stage (each stage: a stride-2
            conv and a stride-1 conv, 3x3, BatchNorm, ReLU); the input shrinks by 2**len(widths).
        hidden: width of the hidden layer of the regression head.
        residual_offset, residual_scale: a residual pixel r (0-255, 127 = no change) enters the
            network as (r - residual_offset) / residual_scale.
        force_mean, force_std: [Fx, Fy, Fz] in N; the network predicts (F - mean) / std.
        contact_threshold, min_contact_fraction: contact gate of ``predict``: a frame with fewer than
            ``min_contact_fraction`` of its pixels deviating by more than ``contact_threshold`` grey
            levels from 127 (any channel) shows no contact and reads exactly [0, 0, 0] N.
            ``contact_threshold=None`` turns the gate off. Sensor noise is ~1-2 grey levels.
        input_kind: "residual" (background-subtracted with the 127 offset); recorded so a
            checkpoint says what it reads.
    """

    input_height: int = 64
    input_width: int = 80
    widths: tuple[int, ...] = (16, 32, 64, 96)
    hidden: int = 128
    residual_offset: float = 127.0
    residual_scale: float = 32.0
    force_mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    contact_threshold: float | None = 8.0
    min_contact_fraction: float = 2e-4
    input_kind: str = "residual"
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.widths = tuple(int(w) for w in self.widths)
        self.force_mean = tuple(float(v) for v in self.force_mean)
        self.force_std = tuple(float(v) for v in self.force_std)
        for name in ("input_height", "input_width"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 16:
                raise ValueError(f"EstimatorConfig.{name} must be an int >= 16 (pixels), got {v!r}")
        if not 1 <= len(self.widths) <= 6 or any(w < 1 for w in self.widths):
            raise ValueError(f"EstimatorConfig.widths must be 1 to 6 positive ints (channels per stage), got {self.widths!r}")
        if self.hidden < 1:
            raise ValueError(f"EstimatorConfig.hidden must be a positive int, got {self.hidden!r}")
        if not self.residual_scale > 0:
            raise ValueError(f"EstimatorConfig.residual_scale must be > 0, got {self.residual_scale!r}")
        if len(self.force_mean) != 3 or len(self.force_std) != 3:
            raise ValueError("EstimatorConfig.force_mean and force_std must each have 3 values [Fx, Fy, Fz] in N")
        if any(not s > 0 for s in self.force_std):
            raise ValueError(f"EstimatorConfig.force_std must be > 0 per axis (N), got {self.force_std!r}")
        if self.contact_threshold is not None and not 0 < self.contact_threshold < 128:
            raise ValueError(f"EstimatorConfig.contact_threshold must be in (0, 128) grey levels or None, got {self.contact_threshold!r}")
        if not 0 <= self.min_contact_fraction < 1:
            raise ValueError(f"EstimatorConfig.min_contact_fraction must be in [0, 1), got {self.min_contact_fraction!r}")
        if self.input_kind != "residual":
            raise ValueError(f"EstimatorConfig.input_kind must be 'residual', got {self.input_kind!r}")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["widths"] = list(self.widths)
        d["force_mean"] = list(self.force_mean)
        d["force_std"] = list(self.force_std)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "EstimatorConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown EstimatorConfig fields {sorted(unknown)}; expected a subset of {sorted(known)}")
        return cls(**d)

    @classmethod
    def load(cls, path: str | Path) -> "EstimatorConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))
