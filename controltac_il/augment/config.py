"""``ForceAugmentConfig``: every setting of ForceAugment, each field with its help (the CLI is built from it)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

MODES = ("cache", "online")
OUT_OF_RANGE = ("clamp", "skip")
BUILD = ("now", "require", "manual")


def _setting(default, help: str, flag: bool = True, **argparse_kwargs):
    """A config field: its default, its help, and how the CLI reads it (``flag=False`` keeps it off the
    command line; ``argparse_kwargs``: type, nargs, choices, metavar of its flag)."""
    return field(default=default, metadata={"help": help, "cli": argparse_kwargs if flag else None})


def _int(value, name: str, low: int, none_ok: bool = False) -> int | None:
    if value is None and none_ok:
        return None
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < low:
        raise ValueError(f"{name}: expected {'None or ' if none_ok else ''}an int >= {low}, got {value!r}")
    return int(value)


def _floats(value, name: str, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, got {value!r}") from exc
    return out


@dataclass
class ForceAugmentConfig:
    """Settings of ForceAugment (everything that decides the augmented frames is recorded in the cache).

    Each field's help is in its metadata (``ForceAugmentConfig.help()``); the list follows."""

    copies: int = _setting(4, "augmented copies per episode (>= 0); the wrapper has (copies + 1) x the wrapped length",
                           type=int)
    offset_range: tuple[float, float] = _setting(
        (-3.0, 10.0), "(low, high) N: the per-copy normal-force offset is drawn from U[low, high]",
        type=float, nargs=2, metavar=("LOW", "HIGH"))
    jitter: tuple[float, ...] = _setting((-1.0, -0.5, 0.0, 0.5, 1.0),
                                         "per-frame normal-force jitter values (N), one drawn uniformly per frame",
                                         type=float, nargs="+")
    tactile_keys: tuple[str, ...] | None = _setting(
        None, "item keys of the tactile images; None = every key containing 'tactile' (but not "
              "'tactile_background'); a plain sensor name s means observation.tactile.s", nargs="+")
    mode: str = _setting("cache", "'cache' (generate once, store, read back) or 'online' (generate on access)",
                         flag=False)
    cache_dir: str | None = _setting(None, "cache folder (mode 'cache'); None = a folder named after the settings "
                                           "under controltac_il.io.cache_root()/augment", flag=False)
    out_of_range: str = _setting("clamp", "target outside the generator's validated force range: 'clamp' (the "
                                          "generator moves it into range) or 'skip' (keep the real frame); both "
                                          "are counted", choices=OUT_OF_RANGE)
    seed: int = _setting(0, "root of every random draw (int >= 0)", type=int)
    steps: int | None = _setting(None, "sampler steps; None = the generator's default", type=int)
    contact_force: float = _setting(0.2, "with force labels, a frame is in contact when Fz >= this (N)", type=float)
    min_contact_area: float = _setting(
        0.002, "without force labels, a frame is in contact when at least this fraction of its pixels are "
               "contact pixels of contact_mask on the residual", type=float)
    batch_size: int = _setting(32, "frames per generator call while building the cache (1: bit-identical to "
                                   "mode 'online', which generates frame by frame)", type=int)
    force_keys: dict | None = _setting(
        None, "{tactile key: item key of its force label [Fx, Fy, Fz] N, or None}; keys left out follow the rule "
              "observation.tactile.<s> -> observation.force.<s> (keys containing 'tactile' only); no label: the "
              "force estimator gives the reference force", flag=False)
    background_keys: dict | None = _setting(
        None, "{tactile key: item key of its no-contact background image, or None}; keys left out follow the rule "
              "observation.tactile.<s> -> observation.tactile_background.<s>; none: estimated per episode from "
              "the episode's own frames", flag=False)
    window_offsets: dict | None = _setting(
        None, "{tactile key: frame offsets of its window positions from the item's frame} for keys holding "
              "(T, C, H, W) windows; default: the dataset's delta_indices, else delta_timestamps x fps", flag=False)
    pose_offset: tuple[float, float, float] | None = _setting(
        None, "stage 2, off by default as in the paper's policies: (max_dx_px, max_dy_px, max_dtheta_deg); each copy "
              "also moves every contact by one rigid offset drawn U[-max, max] per component (pixels of the tactile "
              "images, dy down; degrees counter-clockwise), through the generator's pose adapter on the frame's "
              "contact pixels; frames without contact pixels to move get the force change alone", type=float, nargs=3,
        metavar=("DX", "DY", "DTHETA"))
    fps: float | None = _setting(None, "frame rate turning the dataset's delta_timestamps (s) into frame offsets; "
                                       "default: the dataset's fps (LeRobot: dataset.fps)", flag=False)

    def __post_init__(self):
        self.copies = _int(self.copies, "copies", 0)
        rng = _floats(self.offset_range, "offset_range", "(low, high) in N")
        if len(rng) != 2 or not all(math.isfinite(v) for v in rng):
            raise ValueError(f"offset_range: expected two finite numbers (low, high) in N, got {self.offset_range!r}")
        if rng[0] > rng[1]:
            raise ValueError(f"offset_range: inverted, expected low <= high in N, got low {rng[0]:g} > high {rng[1]:g}")
        self.offset_range = rng
        jit = _floats(self.jitter, "jitter", "a sequence of numbers in N")
        if not jit or not all(math.isfinite(v) for v in jit):
            raise ValueError(f"jitter: expected a non-empty sequence of finite numbers in N, got {self.jitter!r}")
        self.jitter = jit
        if self.tactile_keys is not None:
            keys = (self.tactile_keys,) if isinstance(self.tactile_keys, str) else tuple(self.tactile_keys)
            if not keys or not all(isinstance(k, str) and k for k in keys):
                raise ValueError(f"tactile_keys: expected non-empty key names, got {self.tactile_keys!r}")
            self.tactile_keys = keys
        for name, allowed in (("mode", MODES), ("out_of_range", OUT_OF_RANGE)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name}: expected one of {allowed}, got {getattr(self, name)!r}")
        self.seed = _int(self.seed, "seed", 0)
        if self.steps is not None and (not isinstance(self.steps, (int, np.integer)) or self.steps < 1):
            raise ValueError(f"steps: expected None or an int >= 1, got {self.steps!r}")
        if not (isinstance(self.contact_force, (int, float, np.number)) and 0 <= self.contact_force < math.inf):
            raise ValueError(f"contact_force: expected a finite number >= 0 (N), got {self.contact_force!r}")
        if not 0 <= self.min_contact_area < 1:
            raise ValueError(f"min_contact_area: expected a fraction in [0, 1), got {self.min_contact_area!r}")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ValueError(f"batch_size: expected an int >= 1, got {self.batch_size!r}")
        for name in ("force_keys", "background_keys"):
            self._check_mapping(name)
        if self.window_offsets is not None:
            self._check_mapping("window_offsets")
            try:
                self.window_offsets = {k: tuple(_int(o, "window_offsets", -10**9) for o in v)
                                       for k, v in self.window_offsets.items()}
            except (TypeError, ValueError) as exc:
                raise ValueError(f"window_offsets: expected {{tactile key: [int frame offsets]}}, got "
                                 f"{self.window_offsets!r}") from exc
        if self.pose_offset is not None:
            off = _floats(self.pose_offset, "pose_offset", "(max_dx_px, max_dy_px, max_dtheta_deg)")
            if len(off) != 3 or not all(math.isfinite(v) and v >= 0 for v in off):
                raise ValueError(f"pose_offset: expected None or three finite numbers >= 0 (max_dx_px, max_dy_px, "
                                 f"max_dtheta_deg), got {self.pose_offset!r}")
            self.pose_offset = off
        if self.fps is not None and not (isinstance(self.fps, (int, float, np.number)) and 0 < self.fps < math.inf):
            raise ValueError(f"fps: expected None or a frame rate > 0, got {self.fps!r}")

    def _check_mapping(self, name: str) -> None:
        value = getattr(self, name)
        if value is None:
            return
        if not isinstance(value, dict) or not all(isinstance(k, str) and k for k in value):
            raise ValueError(f"{name}: expected a dict {{tactile key: item key or None}}, got {value!r}")
        if name != "window_offsets" and not all(v is None or (isinstance(v, str) and v) for v in value.values()):
            raise ValueError(f"{name}: expected item keys (str) or None as values, got {value!r}")
        setattr(self, name, dict(value))

    @classmethod
    def help(cls) -> dict[str, str]:
        """Field name -> its documented help."""
        return {f.name: f.metadata["help"] for f in dataclasses.fields(cls)}


ForceAugmentConfig.__doc__ += "\n" + "".join(
    f"\n    {name}: {text}." for name, text in ForceAugmentConfig.help().items()) + "\n"
