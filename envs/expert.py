"""Scripted peg-in-hole expert with injected noise (privileged: it reads the peg and hole poses).

Phases (control steps at 10 Hz): approach above the peg, descend, close, lift, carry the peg over
the hole, align, insert, hold (from "carry" on when the scene starts with the peg in the hand). Each phase interpolates the target linearly from where the previous
one ended to its goal; goals that depend on the scene (where the peg sits in the hand) are computed
when the phase starts, and while aligning and inserting the horizontal target is re-aimed every
step at the peg's actual bottom, so the expert corrects the in-hand offset and swing it got.

Noise, drawn from the episode's generator: per-episode in-hand offset (grasp point along the gel,
grasp depth below the peg's top) and per-step Gaussian target noise, smaller near the hole.
"""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import Field
from pydantic.dataclasses import dataclass

from controltac_il.config import STRICT
from envs.config import bounded_range, finite, one_line_errors
from envs.geometry import BASE_THICKNESS_M, rim_height_m
from envs.peg_in_hole import PegInHoleEnv

NonNegativeMm = Annotated[float, finite("mm"), Field(ge=0)]
GraspOffsetRange = bounded_range(-8.0, 8.0)  # mm along the gel from the peg axis
GraspDepthRange = bounded_range(8.0, 40.0)  # mm below the peg's top


@one_line_errors
@dataclass(config=STRICT)
class ExpertConfig:
    """Scripted expert settings (a pydantic dataclass like ``PegInHoleConfig``: an invalid field raises a
    one-line ValueError naming it).

    free_noise_mm: std of the per-step target noise (x, y, z) while moving in free space (mm).
    fine_noise_mm: std of the per-step target noise while aligning and inserting (mm); must stay
        well under the radial clearance (2.5 mm for the Ø30 mm hole).
    yaw_noise_rad: std of the per-step yaw noise (rad).
    grasp_offset_mm: (low, high) of the grasp point's offset along the gel from the peg axis (mm).
    grasp_depth_mm: (low, high) of the TCP's depth below the peg's top face (mm); the gel is 15.2 mm
        tall, so >= 8 keeps it fully on the peg.
    clearance_mm: height of the peg's bottom above the rim while carrying (mm).
    floor_gap_mm: the insertion stops with the peg's bottom this far above the hole's floor (mm).
    """

    free_noise_mm: NonNegativeMm = 1.0
    fine_noise_mm: NonNegativeMm = 0.25
    yaw_noise_rad: Annotated[float, finite("rad"), Field(ge=0)] = 0.01
    grasp_offset_mm: GraspOffsetRange = (-3.0, 3.0)
    grasp_depth_mm: GraspDepthRange = (14.0, 22.0)
    clearance_mm: NonNegativeMm = 25.0
    floor_gap_mm: NonNegativeMm = 3.0


# (phase, control steps)
PHASES = (("approach", 12), ("descend", 8), ("close", 5), ("lift", 8), ("carry", 14), ("align", 6),
          ("insert", 14), ("hold", 5))
IN_HAND_PHASES = PHASES[4:]  # PegInHoleConfig.peg_in_hand: the episode starts with the peg held


def wrap_half_turn(yaw: float) -> float:
    """Yaw wrapped to [-pi/2, pi/2): a parallel gripper is symmetric under a half turn."""
    return (yaw + math.pi / 2) % math.pi - math.pi / 2


class ScriptedExpert:
    """Drives a ``PegInHoleEnv`` through one episode; call ``reset`` after each ``env.reset``.

    ``act()`` returns the next action (5,) float32; after the last phase it keeps holding.
    """

    def __init__(self, env: PegInHoleEnv, config: ExpertConfig | None = None):
        self.env = env
        self.config = config or ExpertConfig()
        self._rng = np.random.default_rng()

    def reset(self, seed: int) -> None:
        """Start a new plan for the current episode; ``seed`` draws the expert's noise."""
        cfg = self.config
        self._rng = np.random.default_rng(seed)
        self._offset = self._rng.uniform(*cfg.grasp_offset_mm) / 1000.0
        self._depth = self._rng.uniform(*cfg.grasp_depth_mm) / 1000.0
        self._phases = IN_HAND_PHASES if self.env.config.peg_in_hand else PHASES
        self._phase = 0
        self._k = 0
        self._start = self.env.command
        self._goal = self._goal_for(self._phases[0][0])
        self._last = self._start.copy()

    @property
    def phase(self) -> str:
        """Name of the current phase ("done" after the plan)."""
        return self._phases[self._phase][0] if self._phase < len(self._phases) else "done"

    def act(self) -> np.ndarray:
        """Next action [x, y, z, yaw, gripper] (float32 (5,))."""
        if self._phase >= len(self._phases):
            return self._last.astype(np.float32)
        name, n = self._phases[self._phase]
        self._k += 1
        target = self._start + (self._goal - self._start) * (self._k / n)
        fine = name in ("align", "insert", "hold")
        if fine:
            # closed loop on the peg: it swings a little in the soft grip while carried, so re-aim
            # the TCP every step to put the peg's current bottom centre over the hole
            held = self.env.peg_bottom()[:2] - self.env.tcp_pose()[:2]
            target[:2] = self.env.hole_xy - held
        sigma = (self.config.fine_noise_mm if fine else self.config.free_noise_mm) / 1000.0
        noisy = target.copy()
        noisy[:3] += self._rng.normal(0.0, sigma, 3)
        noisy[3] += self._rng.normal(0.0, self.config.yaw_noise_rad)
        if self._k >= n:
            self._phase += 1
            self._k = 0
            self._start = target
            if self._phase < len(self._phases):
                self._goal = self._goal_for(self._phases[self._phase][0])
        self._last = noisy
        return noisy.astype(np.float32)

    def _goal_for(self, name: str) -> np.ndarray:
        env, s = self.env, self._start
        pos, rot = env.peg_pose()
        if name in ("approach", "descend"):
            yaw = wrap_half_turn(math.atan2(rot[1, 0], rot[0, 0]))
            xy = pos[:2] + self._offset * np.array([math.cos(yaw), math.sin(yaw)])
            top = pos[2] + env.peg_half_length_m
            z = top - self._depth + (0.05 if name == "approach" else 0.0)
            return np.array([*xy, z, yaw, 0.0])
        if name == "close":
            return np.array([*s[:4], 1.0])
        if name == "lift":
            bottom = env.peg_bottom()
            rise = rim_height_m(env.config.hole_depth_mm) + self.config.clearance_mm / 1000.0 - bottom[2]
            return np.array([*s[:2], s[2] + rise, s[3], 1.0])
        if name in ("carry", "align"):
            # move the TCP so the peg's bottom centre (as held now) lands over the hole's centre
            held = env.peg_bottom()[:2] - env.tcp_pose()[:2]
            return np.array([*(env.hole_xy - held), s[2], s[3], 1.0])
        if name == "insert":
            floor = BASE_THICKNESS_M + self.config.floor_gap_mm / 1000.0
            drop = env.peg_bottom()[2] - floor
            return np.array([*s[:2], s[2] - drop, s[3], 1.0])
        return s.copy()  # hold
