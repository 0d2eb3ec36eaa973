"""Configuration of the force estimator (model shape, input normalisation, force units): a pydantic dataclass."""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.config import JsonConfig, Positive, STRICT, one_line_errors
from controltac_il.tactile.residual import OFFSET

if TYPE_CHECKING:
    import torch

Finite = Annotated[float, Field(allow_inf_nan=False)]


@one_line_errors
@dataclass(config=STRICT)
class EstimatorConfig(JsonConfig):
    """Shape and normalisation of a :class:`~controltac_il.estimators.model.ForceCNN`; every field is
    validated at construction (ValueError naming it).

    Fields:
        input_height, input_width: pixel size (>= 16) the network sees; residuals of any other size are
            resized to it (area-averaged when shrinking), so one checkpoint reads 240x320 GelSight
            frames and the generator's 128x160 frames alike (same physical pad).
        widths: output channels of the stride-2 stages, one to six entries (each stage: a stride-2
            conv and a stride-1 conv, 3x3, BatchNorm, ReLU); the input shrinks by 2**len(widths).
        hidden: width of the hidden layer of the regression head.
        residual_offset, residual_scale: a residual pixel r (0-255, ``residual.OFFSET`` = no change) enters
            the network as (r - residual_offset) / residual_scale.
        force_mean, force_std: [Fx, Fy, Fz] in N; the network predicts (F - mean) / std (std > 0).
        contact_threshold, min_contact_fraction: contact gate of ``predict``: a frame with fewer than
            ``min_contact_fraction`` of its pixels deviating by more than ``contact_threshold`` grey
            levels (0-128) from 127 (any channel) shows no contact and reads exactly [0, 0, 0] N.
            ``contact_threshold=None`` turns the gate off. Sensor noise is ~1-2 grey levels.
        input_mix, input_shift: a sensor's colour calibration (``estimators.few_shot``): the normalised input's
            colour channels c (3,) enter the network as input_mix @ c + input_shift; None = identity (the
            sensor the network was trained on).
        input_kind: "residual" (background-subtracted with the 127 offset); recorded so a
            checkpoint says what it reads.
        extra: free-form notes kept with the config.
    """

    input_height: Annotated[int, Field(ge=16)] = 64
    input_width: Annotated[int, Field(ge=16)] = 80
    widths: Annotated[tuple[Annotated[int, Field(ge=1)], ...], Field(min_length=1, max_length=6)] = (16, 32, 64, 96)
    hidden: Annotated[int, Field(ge=1)] = 128
    residual_offset: Finite = float(OFFSET)
    residual_scale: Positive = 32.0
    force_mean: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    force_std: tuple[Positive, Positive, Positive] = (1.0, 1.0, 1.0)
    contact_threshold: Annotated[float, Field(gt=0, lt=128)] | None = 8.0
    min_contact_fraction: Annotated[float, Field(ge=0, lt=1)] = 2e-4
    input_mix: tuple[tuple[Finite, Finite, Finite], tuple[Finite, Finite, Finite], tuple[Finite, Finite, Finite]] | None = None
    input_shift: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    input_kind: Literal["residual"] = "residual"
    extra: dict = field(default_factory=dict)


@one_line_errors
@dataclass(config=STRICT)
class EstimatorTrainConfig:
    """Optimisation settings (pydantic: validated at construction, ValueError naming the field).

    Fields:
        steps: number of AdamW updates (fixed budget, independent of the data size).
        batch_size: images per update.
        lr, min_lr: peak and final learning rate of the cosine schedule (after ``warmup`` steps), 0 <= min_lr <= lr.
        warmup: linear warm-up steps.
        weight_decay: AdamW weight decay.
        seed: seeds the weights and the batch sampler.
        checkpoint_every: write resumable state every this many steps (0 = only at the end).
        eval_every: evaluate on the validation arrays every this many steps (0 = only at the end).
    """

    steps: Annotated[int, Field(ge=1)] = 3000
    batch_size: Annotated[int, Field(ge=1)] = 64
    lr: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 2e-3
    min_lr: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 2e-5
    warmup: Annotated[int, Field(ge=0)] = 100
    weight_decay: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 1e-4
    seed: Annotated[int, Field(ge=0)] = 0  # numpy's generators take no negative seed
    checkpoint_every: Annotated[int, Field(ge=0)] = 250
    eval_every: Annotated[int, Field(ge=0)] = 500

    @model_validator(mode="after")
    def _floor(self):
        if self.min_lr > self.lr:
            raise ValueError(f"min_lr={self.min_lr} must be <= lr={self.lr}")
        return self

    def schedule(self, opt: torch.optim.Optimizer, resume: dict | None = None, step: int = 0):
        """Linear warm-up, then cosine decay to ``min_lr`` (torch schedulers; see ``controltac_il.training.lr_schedule``)."""
        from controltac_il.training import lr_schedule

        return lr_schedule(opt, [self.lr], self.steps, self.warmup, self.min_lr, resume, step)
