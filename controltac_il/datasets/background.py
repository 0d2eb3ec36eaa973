"""A tactile sensor's no-contact background: estimated from an episode's own frames, or read from the image
file a lab recorded of its sensor at rest (``read_background_image``).

Estimated where a recording has no ``/observations/tactile_background/<sensor>``. No-contact frames are
those with a labelled normal force below ``no_contact_force`` (N) when labels exist; otherwise (or when
no label is that low, with a warning) the frames that barely differ from the episode's first frames (a
demonstration starts before the grasp). The background is the per-pixel median of those frames (median
removes the sensor noise).
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import cv2
import numpy as np

MAX_FRAMES = 64  # frames used for the median (evenly spaced), bounds memory and time


def changed_fraction(frames: np.ndarray, reference: np.ndarray, threshold: int = 12) -> np.ndarray:
    """Fraction of pixels per frame whose largest channel difference to ``reference`` exceeds ``threshold``.

    frames: uint8 (T, H, W, 3); reference: uint8 (H, W, 3) -> float (T,).
    """
    diff = np.abs(frames.astype(np.int16) - reference.astype(np.int16)).max(axis=-1)
    return (diff > threshold).mean(axis=(1, 2))


def estimate_background(
    frames: np.ndarray,
    force: np.ndarray | None = None,
    no_contact_force: float = 0.1,
    max_changed_fraction: float = 0.005,
) -> tuple[np.ndarray, np.ndarray]:
    """Background (uint8 (H, W, 3)) and the indices of the no-contact frames it was taken from.

    frames: uint8 (T, H, W, 3) tactile images of one episode; force: optional float (T, 3) labels
    [Fx, Fy, Fz] N (Fz > 0 pressing). Falls back to the least-changed tenth of the frames when no
    frame qualifies as no-contact.
    """
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise ValueError(f"frames: expected uint8 (T, H, W, 3) with T >= 1, got {frames.dtype} {frames.shape}")
    idle = np.zeros(0, dtype=np.int64)
    if force is not None:
        force = np.asarray(force, dtype=np.float32)
        if force.shape != (len(frames), 3):
            raise ValueError(f"force: expected shape ({len(frames)}, 3), got {force.shape}")
        idle = np.flatnonzero(force[:, 2] < no_contact_force)
        if len(idle) == 0:  # in contact throughout, or a sensor reading an offset: the labels cannot say which
            warnings.warn(f"no frame's force label is below {no_contact_force:g} N (lowest "
                          f"{float(np.nanmin(force[:, 2])):.2f} N): the background is taken from the frames unchanged "
                          "from the episode's start, which hold the contact if it starts in one; record the "
                          "no-contact background to be sure (background_images=, --background-image)", stacklevel=2)
    if len(idle) == 0:
        start = np.median(frames[: min(5, len(frames))], axis=0).astype(np.uint8)
        change = changed_fraction(frames, start)
        idle = np.flatnonzero(change <= max_changed_fraction)
        if len(idle) == 0:
            idle = np.sort(np.argsort(change, kind="stable")[: max(1, len(frames) // 10)])
    if len(idle) > MAX_FRAMES:
        idle = idle[np.linspace(0, len(idle) - 1, MAX_FRAMES).round().astype(np.int64)]
    background = np.median(frames[idle], axis=0).round().astype(np.uint8)
    return background, idle


def read_background_image(path, field: str = "background_images") -> np.ndarray:
    """The no-contact image a lab recorded of its sensor at rest (an 8-bit RGB PNG or JPEG file) as uint8
    (H, W, 3) RGB; ValueError naming ``field`` and the file for a missing, unreadable or non-RGB one."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"{field}: expected an image file's path, got {type(path).__name__}")
    if not os.fspath(path):  # Path("") would be ".", the working folder
        raise ValueError(f"{field}: the image file's path is empty (expected the sensor's no-contact image, a PNG)")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{field}: {path} is not a file (expected the sensor's no-contact image, a PNG)")
    image = _decode(np.fromfile(path, np.uint8))
    if image is None:
        raise ValueError(f"{field}: {path} is not a readable image file (expected a PNG or JPEG)")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[-1] != 3:
        channels = image.shape[-1] if image.ndim == 3 else 1
        raise ValueError(f"{field}: {path} is {image.dtype} with {channels} channel(s); expected an 8-bit RGB image "
                         "(the tactile camera's own frames)")
    return np.ascontiguousarray(image[..., ::-1])


def _decode(data: np.ndarray) -> np.ndarray | None:
    """An encoded image's pixels, or None where OpenCV cannot read it (empty bytes, on which it asserts, included),
    with its own warning about a truncated file kept off stderr: the caller's refusal is the one line."""
    if not len(data):
        return None
    log = cv2.utils.logging
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_ERROR)
    try:
        return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    finally:
        log.setLogLevel(level)


def check_background_size(image: np.ndarray, frame_hw: tuple, field: str, where: str) -> None:
    """ValueError naming ``field`` when ``image`` (H, W, 3) is not the size ``frame_hw`` of ``where``'s frames."""
    if tuple(image.shape[:2]) != tuple(frame_hw):
        raise ValueError(f"{field}: the image for {where} is {image.shape[1]}x{image.shape[0]} (W x H); its "
                         f"frames are {frame_hw[1]}x{frame_hw[0]}: record it with the same camera settings")


def given_backgrounds(given, names: dict[str, tuple[str, ...]], frame_hw: dict[str, tuple[int, int]]) -> dict:
    """{sensor: uint8 (H, W, 3)} of ``background_images`` ({a sensor's name or one of its keys ``names[s]``:
    image file}), read and checked against that sensor's frame size ``frame_hw[s]``; ValueError naming the
    setting for an unknown or twice-named sensor."""
    if given is None:
        return {}
    if not isinstance(given, dict):
        raise ValueError(f"background_images: expected {{tactile sensor: image file path}}, got {type(given).__name__}")
    out = {}
    for name, path in given.items():
        s = next((s for s, keys in names.items() if name == s or name in keys), None)
        if s is None:
            raise ValueError(f"background_images: {name!r} is not a tactile sensor of the data; those are "
                             f"{list(names)}")
        if s in out:
            raise ValueError(f"background_images: {s!r} is named twice")
        out[s] = read_background_image(path)
        check_background_size(out[s], frame_hw[s], "background_images", repr(names[s][0]))
    return out


def episode_background_digests(backgrounds: dict) -> dict[str, str]:
    """{sensor: the first 16 hex digits of the SHA-256 of every episode's background pixels, in episode order} of
    ``backgrounds`` {(episode, sensor): uint8 (H, W, 3)}: what a training run records of the backgrounds it trained
    on, so that resuming on the same frames with another episode's background (or any other) is told apart."""
    out = {}
    for s in dict.fromkeys(s for _, s in backgrounds):
        h = hashlib.sha256()
        for e in sorted(e for e, t in backgrounds if t == s):
            bg = backgrounds[(e, s)]
            if not isinstance(bg, np.ndarray) or bg.dtype != np.uint8 or bg.ndim != 3:
                raise ValueError(f"backgrounds: episode {e}'s {s!r} is {type(bg).__name__}, not a uint8 (H, W, 3) "
                                 "image")
            h.update(np.ascontiguousarray(bg).tobytes())
        out[s] = h.hexdigest()[:16]
    return out


def image_digests(images: dict) -> dict[str, str]:
    """{name: the first 16 hex digits of the SHA-256 of its pixels}: what a cache or fingerprint records of a
    given image (moving the file keeps it, editing a pixel does not)."""
    return {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest()[:16] for k, v in images.items()}
