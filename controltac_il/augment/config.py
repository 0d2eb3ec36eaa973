"""``ForceAugmentConfig``: every setting of ForceAugment, each field with its help (the CLI is built from it).

The project's config idiom (``controltac_il.config``): a pydantic dataclass; each field's check runs before its type
is validated and says what it expects, ``one_line`` puts the field's name in front (one-line ValueError)."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import field

import numpy as np
from pydantic import field_validator
from pydantic.dataclasses import dataclass

from controltac_il.generator.forces import NOMINAL_FZ, VALIDATED_RANGE
from controltac_il.config import AUTO, STRICT, is_int, one_line_errors, parse_batch_size

MODES = ("cache", "online")
OUT_OF_RANGE = ("clamp", "skip")
ESTIMATED_REFERENCE = ("nominal", "clip", "skip")
BUILD = ("now", "require", "manual")


def _setting(default, help: str, flag: bool = True, **argparse_kwargs):
    """A config field: its default, its help, and how the CLI reads it (``flag=False`` keeps it off the
    command line; ``argparse_kwargs``: type, nargs, action, choices, metavar of its flag)."""
    return field(default=default, metadata={"help": help, "cli": argparse_kwargs if flag else None})


def _int(value, low: int, none_ok: bool = False) -> int | None:
    if value is None and none_ok:
        return None
    if not is_int(value) or value < low:
        raise ValueError(f"expected {'None or ' if none_ok else ''}an int >= {low}")
    return int(value)


def _floats(value, what: str) -> tuple[float, ...]:
    if isinstance(value, (str, bytes)):  # "12" would read as (1.0, 2.0)
        raise ValueError(f"expected {what}")
    try:
        return tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"expected {what}") from None


def _finite(value, what: str, count: int | None = None) -> tuple[float, ...]:
    """Non-empty finite floats (``count`` of them if given), else ValueError("expected <what>")."""
    out = _floats(value, what)
    if not out or (count is not None and len(out) != count) or not all(math.isfinite(x) for x in out):
        raise ValueError(f"expected {what}")
    return out


# A normal-force shift (offset, jitter) or a target beyond the validated range's top leaves every target outside
# it: each would be clamped or skipped, so such settings are refused rather than run.
MAX_SHIFT_N = VALIDATED_RANGE.fz[1]


def _shifts(values: tuple[float, ...], what: str) -> tuple[float, ...]:
    """``values`` when each is within +-MAX_SHIFT_N, else ValueError naming the bound."""
    if any(abs(x) > MAX_SHIFT_N for x in values):
        raise ValueError(f"{what} must lie within +-{MAX_SHIFT_N:g} N (beyond it every target leaves the "
                         "generator's validated range)")
    return values


def _number(value, what: str, low: float = 0.0, high: float = math.inf, none_ok: bool = False) -> float | None:
    if value is None and none_ok:
        return None
    if not isinstance(value, (int, float, np.number)) or isinstance(value, bool) or not low <= value < high:
        raise ValueError(f"expected {'None or ' if none_ok else ''}{what}")
    return float(value)


def _key_map(value, values_are_keys: bool = True) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict) or not all(isinstance(k, str) and k for k in value):
        raise ValueError("expected a dict {tactile key: item key or None}")
    if values_are_keys and not all(v is None or (isinstance(v, str) and v) for v in value.values()):
        raise ValueError("expected item keys (str) or None as values")
    return dict(value)


@one_line_errors
@dataclass(config=STRICT)
class ForceAugmentConfig:
    """Settings of ForceAugment (everything that decides the augmented frames is recorded in the cache).

    Each field's help is in its metadata (``ForceAugmentConfig.help()``); the list follows."""

    copies: int = _setting(4, "augmented copies per episode (>= 0; the command needs >= 1); the wrapper has (copies + 1) x "
                              "the wrapped length",
                           type=int)
    offset_range: tuple[float, float] = _setting(
        (-3.0, 10.0), "(low, high) N, each within +-10: the per-copy normal-force offset is drawn from U[low, high]",
        type=float, nargs=2, metavar=("LOW", "HIGH"))
    target_range: tuple[float, float] | None = _setting(
        None, "(low, high) N in [0, 10], or None: when set, each copy's offset is drawn so that the copy's targets spread over "
              "this range instead of offset_range: offset = U[low, high] - the episode's median contact Fz (its "
              "reference forces over every tactile key), so the targets sit around U[low, high] N plus the jitter",
        type=float, nargs=2, metavar=("LOW", "HIGH"))
    jitter: tuple[float, ...] = _setting((-1.0, -0.5, 0.0, 0.5, 1.0),
                                         "per-frame normal-force jitter values (N, each within +-10), one drawn "
                                         "uniformly per frame",
                                         type=float, nargs="+")
    tactile_keys: tuple[str, ...] | None = _setting(
        None, "item keys of the tactile images; None = every key containing 'tactile' (but not "
              "'tactile_background'); a plain sensor name s means observation.tactile.s, or "
              "observation.images.s where the items have that", nargs="+", action="extend")
    mode: str = _setting("cache", "'cache' (generate once, store, read back) or 'online' (generate on access; the "
                                  "same bytes as a cache built with the same torch thread count, which a cache "
                                  "records: DataLoader workers run one thread)",
                         flag=False)
    cache_dir: str | None = _setting(None, "cache folder (mode 'cache'); None = a folder named after the settings "
                                           "under controltac_il.io.cache_root()/augment", flag=False)
    out_of_range: str = _setting("clamp", "target outside the generator's validated force range: 'clamp' (the "
                                          "generator moves it into range) or 'skip' (keep the real frame); both "
                                          "are counted", choices=OUT_OF_RANGE)
    estimated_reference: str = _setting(
        "nominal", "an estimated reference force (no label) outside the generator's validated range: 'nominal' "
                   f"uses (0, 0, {NOMINAL_FZ:g}) N (the range's middle) in its place, 'clip' its Fz clipped into the "
                   "range and no shear, "
                   "'skip' keeps the frame real; only ΔF conditions the generator, so the image's own force need "
                   "not be known (benchmarks.unlabelled_real)", choices=ESTIMATED_REFERENCE)
    seed: int = _setting(0, "root of every random draw (int >= 0)", type=int)
    steps: int | None = _setting(None, "sampler steps; None = the generator's default", type=int)
    contact_force: float = _setting(0.2, "with force labels, a frame is in contact when Fz >= this (N)", type=float)
    min_contact_area: float = _setting(
        0.002, "without force labels, a frame is in contact when at least this fraction of its pixels are "
               "contact pixels of contact_mask on the residual", type=float)
    batch_size: int | str = _setting(32, "frames per generator batch while building the cache (memory only: the "
                                         "frames do not depend on it); 'auto': the largest the generator's device "
                                         "holds", type=parse_batch_size)
    force_keys: dict | None = _setting(
        None, "{tactile key: item key of its force label [Fx, Fy, Fz] N, or None}; keys left out follow the rule "
              "observation.tactile.<s> -> observation.force.<s> (keys containing 'tactile' only); no label: the "
              "force estimator gives the reference force", flag=False)
    background_keys: dict | None = _setting(
        None, "{tactile key: item key of its no-contact background image, or None}; keys left out follow the rule "
              "observation.tactile.<s> -> observation.tactile_background.<s>; none: estimated per episode from "
              "the episode's own frames", flag=False)
    background_images: dict | None = _setting(
        None, "{tactile key (or its sensor name): path of an 8-bit RGB image (PNG) of that sensor at rest, no "
              "contact, at the frames' size}; used for every episode in place of the items' background or the "
              "estimate (for recordings that start in contact, or hold no background: LeRobot folders); the cache "
              "records each image's pixels' digest", flag=False)
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

    @field_validator("copies", "seed", mode="before")
    @classmethod
    def _count(cls, v):
        return _int(v, 0)

    @field_validator("steps", mode="before")
    @classmethod
    def _steps(cls, v):
        return _int(v, 1, none_ok=True)

    @field_validator("batch_size", mode="before")
    @classmethod
    def _batch(cls, v):
        if v == AUTO:
            return AUTO
        if not is_int(v) or v < 1:
            raise ValueError("expected an int >= 1 or 'auto'")
        return int(v)

    @field_validator("offset_range", mode="before")
    @classmethod
    def _offset_range(cls, v):
        rng = _finite(v, "two finite numbers (low, high) in N", count=2)
        if rng[0] > rng[1]:
            raise ValueError(f"inverted: low {rng[0]:g} N is above high {rng[1]:g} N")
        return _shifts(rng, "offsets")

    @field_validator("target_range", mode="before")
    @classmethod
    def _target_range(cls, v):
        if v is None:
            return None
        rng = _finite(v, "None or two finite numbers (low, high) in N", count=2)
        if not 0 <= rng[0] <= rng[1] <= MAX_SHIFT_N:
            raise ValueError(f"expected 0 <= low <= high <= {MAX_SHIFT_N:g} N (the validated range's top)")
        return rng

    @field_validator("jitter", mode="before")
    @classmethod
    def _jitter(cls, v):
        return _shifts(_finite(v, "a non-empty sequence of finite numbers in N"), "jitter values")

    @field_validator("tactile_keys", mode="before")
    @classmethod
    def _tactile_keys(cls, v):
        if v is None:
            return None
        keys = (v,) if isinstance(v, str) else tuple(v) if isinstance(v, (list, tuple)) else ()
        if not keys or not all(isinstance(k, str) and k for k in keys):
            raise ValueError("expected non-empty key names")
        return keys

    @field_validator("mode", "out_of_range", "estimated_reference", mode="before")
    @classmethod
    def _choice(cls, v, info):
        allowed = {"mode": MODES, "out_of_range": OUT_OF_RANGE, "estimated_reference": ESTIMATED_REFERENCE}[
            info.field_name]
        if v not in allowed:
            raise ValueError(f"expected one of {allowed}")
        return v

    @field_validator("contact_force", mode="before")
    @classmethod
    def _contact_force(cls, v):
        return _number(v, "a finite number >= 0 (N)")

    @field_validator("min_contact_area", mode="before")
    @classmethod
    def _area(cls, v):
        return _number(v, "a fraction in [0, 1)", high=1.0)

    @field_validator("fps", mode="before")
    @classmethod
    def _fps(cls, v):
        return _number(v, "a frame rate > 0", low=math.ulp(0.0), none_ok=True)

    @field_validator("force_keys", "background_keys", mode="before")
    @classmethod
    def _maps(cls, v):
        return _key_map(v)

    @field_validator("background_images", mode="before")
    @classmethod
    def _images(cls, v):
        if v is None:
            return None
        if not isinstance(v, dict):
            raise ValueError(f"expected {{tactile sensor: image file path}}, got {type(v).__name__}")
        for k, p in v.items():
            if not isinstance(k, str) or not k:
                raise ValueError(f"expected {{tactile sensor: image file path}}, got the key {k!r}")
            if not isinstance(p, (str, os.PathLike)) or not os.fspath(p):
                raise ValueError(f"{k!r}: expected an image file path, got {p!r}")
        return {k: os.fspath(p) for k, p in v.items()}

    @field_validator("window_offsets", mode="before")
    @classmethod
    def _windows(cls, v):
        out = _key_map(v, values_are_keys=False)
        try:
            return None if out is None else {k: tuple(_int(o, -10**9) for o in w) for k, w in out.items()}
        except (TypeError, ValueError):
            raise ValueError("expected {tactile key: [int frame offsets]}") from None

    @field_validator("pose_offset", mode="before")
    @classmethod
    def _pose_offset(cls, v):
        if v is None:
            return None
        off = _floats(v, "(max_dx_px, max_dy_px, max_dtheta_deg)")
        if len(off) != 3 or not all(math.isfinite(x) and x >= 0 for x in off):
            raise ValueError("expected None or three finite numbers >= 0 (max_dx_px, max_dy_px, max_dtheta_deg)")
        return off

    @classmethod
    def help(cls) -> dict[str, str]:
        """Field name -> its documented help."""
        return {f.name: f.metadata["help"] for f in dataclasses.fields(cls)}


ForceAugmentConfig.__doc__ += "\n" + "".join(
    f"\n    {name}: {text}." for name, text in ForceAugmentConfig.help().items()) + "\n"
