"""The main job's settings, apart from the job so that ``python -m controltac_il --help`` reads its defaults
without importing torch or MuJoCo."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field
from pydantic.dataclasses import dataclass

from controltac_il.config import STRICT, one_line_errors


@one_line_errors
@dataclass(config=STRICT)
class PipelineConfig:
    """The main job's sizes (defaults: the embedded default, < 15 min on 2 cores); validated at construction
    (pydantic, ValueError naming the field; :func:`controltac_il.config.one_line` spells it as its flag).

    demos: scripted demos collected in the scene (>= 1). copies: ForceAugment copies (0..9; 0 = real only).
    steps / batch_size: ACT training (cpu preset; >= 1). eval_episodes: seeded deployment episodes
    (>= 1; scene seeds from ``envs.config.EVAL_SEED``, disjoint from the demos').
    generator: generator checkpoint (None = shipped). seed: training / augmentation seed.
    """

    demos: Annotated[int, Field(ge=1)] = 20
    copies: Annotated[int, Field(ge=0, le=9)] = 1
    steps: Annotated[int, Field(ge=1)] = 1500
    batch_size: Annotated[int, Field(ge=1)] = 16
    eval_episodes: Annotated[int, Field(ge=1)] = 10
    generator: str | None = None
    seed: int = 0
