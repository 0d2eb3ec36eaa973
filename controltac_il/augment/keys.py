"""Which item keys ForceAugment reads: tactile images, their force labels and backgrounds, and the frames a
time window holds (LeRobot's ``delta_timestamps``). Decided once, from the first item, by ``resolve_keys``.

Force labels and backgrounds are looked up only under an explicit mapping (``force_keys=`` /
``background_keys=`` {tactile key: item key, or None for none}) or the naming rule of our own layout:
``observation.tactile.<s>`` -> ``observation.force.<s>`` / ``observation.tactile_background.<s>``. The rule
applies only to keys containing "tactile", so it never maps an image to itself; a key found by either way
must hold a force (3,) N (a background: an image of the tactile image's size), else the set-up is refused.
A background image given as a file (``background_images=`` {tactile key or sensor name: path}) is used for
every item in place of either.

A tactile key holding a window (T, C, H, W) (or (T, H, W, C)) needs the frame offset of each position from
the item's frame: ``window_offsets=`` {key: [offsets]}, else the wrapped dataset's ``delta_indices``, else
its ``delta_timestamps`` (s) x ``fps`` (``fps=`` or the dataset's ``fps`` / ``meta.fps``), rounded; offset 0
(the item's own frame) must be one of them, and the items must carry ``<key>_is_pad`` (T,) bool.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from controltac_il.arrays import as_array
from controltac_il.augment.items import put_image, to_hwc_uint8
from controltac_il.datasets.background import given_backgrounds, image_digests
from controltac_il.streams import BACKGROUND, FORCE, HDF5, LEROBOT, lerobot_name, looks_tactile, rule_key, tactile_key

OFFSET_TOLERANCE = 0.01  # frames: a delta_timestamp must be this close to a whole number of frames


@dataclass(frozen=True)
class KeyMap:
    """tactile_keys (augmented, in order); per tactile key: its force label key, background key (or None)
    and window offsets (None: single frames); offsets of force label windows by label key; the background
    images given as files (``background_images``: {tactile key: uint8 (H, W, 3)}), which take the place of an
    item's background (and are put at its background key in the items served, ``put_images``)."""

    tactile_keys: tuple[str, ...]
    labels: dict
    backgrounds: dict
    offsets: dict
    label_offsets: dict
    images: dict = field(default_factory=dict)

    def own(self, key: str) -> int | None:
        """Position of the item's own frame (offset 0) in ``key``'s window; None for single frames."""
        offsets = self.offsets[key]
        return None if offsets is None else offsets.index(0)

    def image(self, item: dict, key: str) -> np.ndarray:
        """uint8 (H, W, 3) of the item's own frame."""
        p = self.own(key)
        return to_hwc_uint8(item[key] if p is None else item[key][p], key)

    def label(self, item: dict, key: str) -> np.ndarray | None:
        """Force label (3,) float64 of the item's own frame, or None where the items carry none."""
        lk = self.labels[key]
        if lk is None:
            return None
        value = as_array(item[lk]).astype(np.float64)
        value = value if value.ndim == 1 else value[self.label_offsets[lk].index(0)]
        if not np.isfinite(value).all():  # else NaN Fz reads as "no contact" and the NaN label is copied on
            raise ValueError(f"{lk}: force label {value.tolist()} is not finite; labels must be finite [Fx, Fy, Fz] N")
        return value

    def background(self, item: dict, key: str) -> np.ndarray | None:
        """uint8 (H, W, 3): the given image, else the item's background; None where neither exists."""
        if key in self.images:
            return self.images[key]
        bk = self.backgrounds[key]
        return None if bk is None else to_hwc_uint8(item[bk], bk)

    def put_images(self, item: dict) -> None:
        """Put each given background image at the item's own background key, where it has one (in its layout
        and dtype): a policy reading the item subtracts the background its regenerated frames were made on."""
        for k, image in self.images.items():
            if self.backgrounds[k] is not None:
                put_image(item, self.backgrounds[k], image.copy())  # the items never share one buffer

    def recorded(self, key: str) -> bool:
        """Whether ``key``'s background is recorded (a given image or an item key), not estimated."""
        return key in self.images or self.backgrounds[key] is not None

    def positions(self, item: dict, key: str, frame: int) -> list[tuple[int | None, int]]:
        """(position, frame) of every frame ``key`` holds, padded positions left out ((None, frame) alone
        for a single frame)."""
        offsets = self.offsets[key]
        if offsets is None:
            return [(None, frame)]
        pad = as_array(item[f"{key}_is_pad"]).astype(bool).reshape(-1)
        if len(pad) != len(offsets) or len(item[key]) != len(offsets):
            raise ValueError(f"window_offsets: {key!r} holds {len(item[key])} frames and {key}_is_pad {len(pad)}, "
                             f"its offsets {len(offsets)}")
        return [(p, frame + o) for p, o in enumerate(offsets) if not pad[p]]

    def label_positions(self, item: dict, key: str, frame: int, target_frame: int) -> list[int | None]:
        """Where the force label of ``target_frame`` sits in the item's label of ``key`` (none, the label,
        or rows of a label window)."""
        lk = self.labels[key]
        if lk is None:
            return []
        offsets = self.label_offsets.get(lk)
        if offsets is None:
            return [None] if target_frame == frame else []
        pad = as_array(item.get(f"{lk}_is_pad", np.zeros(len(offsets), bool))).astype(bool).reshape(-1)
        return [p for p, o in enumerate(offsets) if frame + o == target_frame and not pad[p]]

    def settings(self, explicit_labels: bool, explicit_backgrounds: bool) -> dict:
        """What the cache manifest records of the mapping beyond the tactile keys (only what was given; a given
        image by its pixels' digest, so that moving the file keeps the cache and editing it does not)."""
        out = {}
        if explicit_labels:
            out["force_keys"] = {k: self.labels[k] for k in self.tactile_keys}
        if explicit_backgrounds:
            out["background_keys"] = {k: self.backgrounds[k] for k in self.tactile_keys}
        if self.images:
            out["background_images"] = image_digests(self.images)
        return out


def image_keys(probe: dict) -> list[str]:
    """Keys of the item that hold RGB images or windows of them (what a user may pass as tactile_keys)."""
    out = []
    for k, v in probe.items():
        shape = getattr(v, "shape", None)
        if shape is not None and len(shape) in (3, 4) and 3 in (shape[-3], shape[-1]) and min(shape[-3:]) > 0:
            out.append(k)
    return out


# words in a camera key that suggest a tactile sensor: only for the example in the error message, never detection
SENSOR_WORDS = ("gelsight", "digit", "tactile", "touch", "gel", "tac")


def _tactile_keys(probe: dict, wanted) -> tuple[str, ...]:
    images = image_keys(probe)
    if wanted is None:
        found = [k for k in probe if looks_tactile(k)]
        if not found:
            named = [k for k in images if any(w in k.lower() for w in SENSOR_WORDS)]
            example = named or [tactile_key("<tactile camera>", LEROBOT)]
            raise ValueError(f"tactile_keys: the items have no key containing 'tactile' to detect; their image keys "
                             f"are {images}; name the tactile streams, e.g. ForceAugment(dataset, "
                             f"tactile_keys={example!r})")
        return tuple(found)
    keys = []
    for k in wanted:
        full = next((c for c in (k, tactile_key(k, HDF5), tactile_key(k, LEROBOT)) if c in probe), None)
        if full is None:
            raise ValueError(f"tactile_keys: unknown tactile key {k!r}; the items' image keys are {images}")
        if full not in images:
            raise ValueError(f"tactile_keys: {full!r} is not an RGB image or window of them "
                             f"(shape {tuple(getattr(probe[full], 'shape', ()))}); the items' image keys are {images}")
        keys.append(full)
    if len(set(keys)) != len(keys):
        raise ValueError(f"tactile_keys: a key is named twice: {keys}")
    return tuple(keys)


def _mapped(probe: dict, key: str, given: dict | None, kind: str, name: str, tactile: tuple) -> str | None:
    """The label (``kind`` FORCE) or background (BACKGROUND) key of tactile ``key``: ``given[key]`` when the
    mapping names it, else the naming rule (``streams.rule_key``) where the item has that key."""
    if given is not None and key in given:
        mk = given[key]
        if mk is None:
            return None
        if not isinstance(mk, str) or mk == key or mk in tactile:
            raise ValueError(f"{name}: {key!r} maps to {mk!r}, which is not a separate item key (a tactile "
                             "image is never read as its own force or background)")
        if mk not in probe:
            raise ValueError(f"{name}: {key!r} maps to {mk!r}, which the items do not have; keys: {list(probe)}")
        return mk
    mk = rule_key(key, kind)
    return mk if mk is not None and mk in probe else None


def resolve_keys(probe: dict, config, dataset) -> KeyMap:
    """The KeyMap of the wrapped dataset's items (``probe``: its first item), checked."""
    tactile = _tactile_keys(probe, config.tactile_keys)
    for name in ("force_keys", "background_keys", "window_offsets"):
        extra = sorted(set(getattr(config, name) or {}) - set(tactile))
        if extra:
            raise ValueError(f"{name}: {extra} are not tactile keys; the tactile keys are {list(tactile)}")
    images = given_backgrounds(config.background_images, {k: (k, lerobot_name(k)) for k in tactile},
                               {k: to_hwc_uint8(probe[k][0] if len(probe[k].shape) == 4 else probe[k], k).shape[:2]
                                for k in tactile}) if config.background_images else {}
    labels, backgrounds, offsets, label_offsets = {}, {}, {}, {}
    for k in tactile:
        shape = tuple(probe[k].shape)
        offsets[k] = window_offsets(dataset, probe, k, shape[0], config) if len(shape) == 4 else None
        lk = _mapped(probe, k, config.force_keys, FORCE, "force_keys", tactile)
        if lk is not None:
            label_offsets.update(_check_label(dataset, probe, k, lk, config))
        bk = _mapped(probe, k, config.background_keys, BACKGROUND, "background_keys", tactile)
        if bk is not None and k in images and (config.background_keys or {}).get(k) is not None:
            raise ValueError(f"background_images: {k!r} also has background_keys {bk!r}; give one background")
        if bk is not None:
            _check_background(probe, k, bk, offsets[k] is not None)
        labels[k], backgrounds[k] = lk, bk
    km = KeyMap(tactile, labels, backgrounds, offsets, label_offsets, images)
    for k in tactile:
        km.image(probe, k)
        km.positions(probe, k, 0)
    return km


def _check_background(probe: dict, key: str, bk: str, windowed: bool) -> None:
    """A background must be one RGB image the size of the tactile image."""
    own = to_hwc_uint8(probe[key][0] if windowed else probe[key], key).shape
    shape = tuple(getattr(probe[bk], "shape", ()))
    if len(shape) != 3 or 3 not in (shape[0], shape[-1]) or to_hwc_uint8(probe[bk], bk).shape != own:
        raise ValueError(f"background_keys: {bk!r} (shape {shape}) is not one RGB image the size of {key!r}'s "
                         f"frames {own}; map {key!r} to its background image key or to None (estimated)")


def _check_label(dataset, probe: dict, key: str, lk: str, config) -> dict:
    """A force label must be numbers (3,) N, or a window (T, 3) with offsets; returns {lk: offsets} of a window."""
    value = as_array(probe[lk])
    ok = value.dtype.kind in "fiu" and (value.shape == (3,) or (value.ndim == 2 and value.shape[1] == 3))
    if not ok:
        raise ValueError(f"force_keys: {lk!r} (shape {value.shape}, {value.dtype}) is not a force label "
                         f"[Fx, Fy, Fz] N of {key!r}; map {key!r} to its force key or to None (no labels)")
    if value.ndim == 2:
        return {lk: window_offsets(dataset, probe, lk, value.shape[0], config)}
    return {}


def _attribute(dataset, name: str):
    """``name`` of the dataset or of a dataset it wraps (Subset and the like: ``.dataset``)."""
    seen = 0
    while dataset is not None and seen < 8:
        value = getattr(dataset, name, None)
        if value is not None:
            return value
        dataset, seen = getattr(dataset, "dataset", None), seen + 1
    return None


def window_offsets(dataset, probe: dict, key: str, length: int, config) -> tuple[int, ...]:
    """Frame offsets (from the item's frame) of the ``length`` positions of the window at ``key``."""
    given = (config.window_offsets or {}).get(key)
    source = "window_offsets"
    if given is None and isinstance(_attribute(dataset, "delta_indices"), dict):
        given, source = _attribute(dataset, "delta_indices").get(key), "the dataset's delta_indices"
    deltas = _attribute(dataset, "delta_timestamps")
    if given is None and isinstance(deltas, dict) and key in deltas:
        fps = config.fps or _attribute(dataset, "fps") or getattr(_attribute(dataset, "meta"), "fps", None)
        if not fps:
            raise ValueError(f"fps: {key!r} is a window of delta_timestamps (s); pass fps= (the dataset's frame rate) "
                             f"or window_offsets={{{key!r}: [frame offsets]}}")
        frames = [float(d) * float(fps) for d in deltas[key]]
        if any(abs(f - round(f)) > OFFSET_TOLERANCE for f in frames):
            raise ValueError(f"fps: delta_timestamps of {key!r} {list(deltas[key])} are not whole frames at {fps} fps")
        given, source = [round(f) for f in frames], "delta_timestamps x fps"
    if given is None:
        raise ValueError(f"window_offsets: {key!r} holds a window of {length} frames and nothing says which; pass "
                         f"window_offsets={{{key!r}: [...]}} (frame offsets from the item's frame, e.g. "
                         f"{list(range(1 - length, 1))}) or fps= with a dataset that has delta_timestamps")
    offsets = tuple(int(o) for o in given)
    if len(offsets) != length or 0 not in offsets or len(set(offsets)) != len(offsets):
        raise ValueError(f"window_offsets: {key!r} holds {length} frames; its offsets from {source} {list(offsets)} "
                         "must be that many distinct ints including 0 (the item's own frame)")
    if f"{key}_is_pad" not in probe:
        raise ValueError(f"window_offsets: {key!r} is a window but the items have no {key + '_is_pad'!r} "
                         "(LeRobot's padding mask); ForceAugment needs it to leave padded positions alone")
    return offsets
