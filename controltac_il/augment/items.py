"""Item adapters: images read as uint8 (H, W, 3) and written back in the layout and dtype they came in, and
episode sources read directly. Which item keys are tactile images, force labels and backgrounds (and the
time windows of LeRobot's ``delta_timestamps``) is decided once, in ``keys.resolve_keys``."""

from __future__ import annotations

import numpy as np
import torch

from controltac_il.arrays import as_array
from controltac_il.datasets.act_dataset import EpisodeDataset, EpisodeSubset
from controltac_il.datasets.stage import FrameTable


def is_chw(shape) -> bool:
    """Whether an RGB image of ``shape`` (3, H, W) or (H, W, 3) is channel-first."""
    return shape[0] == 3 and shape[-1] != 3


def to_hwc_uint8(value, key: str) -> np.ndarray:
    """Tactile image of an item (tensor/array, (3, H, W) or (H, W, 3), uint8 or float in [0, 1]) -> uint8 (H, W, 3)."""
    arr = as_array(value)
    if arr.ndim != 3 or 3 not in (arr.shape[0], arr.shape[-1]):
        raise ValueError(f"{key}: expected an RGB image (3, H, W) or (H, W, 3), got shape {arr.shape}")
    if is_chw(arr.shape):
        arr = arr.transpose(1, 2, 0)
    if arr.dtype != np.uint8:
        arr = np.clip(np.round(_unit_float(arr, key) * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(arr)


def _unit_float(arr: np.ndarray, key: str) -> np.ndarray:
    """A float image with values in [0, 1] as float32; ValueError naming ``key`` for any other dtype, a NaN, or
    values outside (e.g. a float image in [0, 255], which rounding would turn white)."""
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{key}: expected a uint8 image or a float one in [0, 1], got dtype {arr.dtype}")
    out = arr.astype(np.float32)
    if not np.isfinite(out).all():
        raise ValueError(f"{key}: the float image holds NaN or inf")
    low, high = float(out.min()), float(out.max())
    if low < -1e-3 or high > 1 + 1e-3:  # a rounding step of a [0, 1] transform is not an error
        raise ValueError(f"{key}: float image values must lie in [0, 1], got [{low:g}, {high:g}] (images in "
                         "[0, 255] are uint8)")
    return out


def like(image: np.ndarray, original):
    """uint8 (H, W, 3) -> the original's container, layout and dtype (None: uint8 (3, H, W) tensor view)."""
    if original is None:
        return torch.from_numpy(image).permute(2, 0, 1)
    chw = is_chw(original.shape)
    if isinstance(original, torch.Tensor):
        out = torch.from_numpy(image)
        out = out.permute(2, 0, 1) if chw else out
        return out if original.dtype == torch.uint8 else (out.to(original.dtype) / 255.0)
    arr = image.transpose(2, 0, 1) if chw else image
    return arr if original.dtype == np.uint8 else (arr.astype(original.dtype) / 255.0)


def put_image(item: dict, key: str, image: np.ndarray, position: int | None = None) -> None:
    """Put a uint8 (H, W, 3) image at ``item[key]`` (``position`` of a window (T, ...)), in the layout and
    dtype of what is there. A window is copied first: the wrapped dataset's tensors are never written to."""
    if position is None:
        item[key] = like(image, item.get(key))
        return
    window = item[key]
    window = window.clone() if isinstance(window, torch.Tensor) else np.array(window, copy=True)
    window[position] = like(image, window[position])
    item[key] = window


def put_force(item: dict, key: str, target, position: int | None = None) -> None:
    """Set the force label ``item[key]`` (row ``position`` of a (T, 3) window) to ``target`` (3,) N, same dtype."""
    orig = item[key]
    t = as_array(target).astype(np.float64)
    if isinstance(orig, torch.Tensor):
        new = orig.clone()
        new[... if position is None else position] = torch.from_numpy(t).to(orig.dtype)
    else:
        new = np.array(orig, copy=True)
        new[... if position is None else position] = t.astype(new.dtype)
    item[key] = new


def episode_frame(item: dict) -> tuple[int, int]:
    """(episode_index, frame_index) of an item, checked."""
    try:
        e, t = int(item["episode_index"]), int(item["frame_index"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError("dataset: items need integer 'episode_index' and 'frame_index'") from exc
    if e < 0 or t < 0:
        raise ValueError(f"dataset: episode_index and frame_index must be >= 0, got {e}, {t}")
    return e, t


def check_probe(probe) -> None:
    """The first item of the wrapped dataset: a dict with episode and frame indices."""
    if not isinstance(probe, dict):
        raise ValueError(f"dataset: items must be dicts (LeRobot convention), got {type(probe).__name__}")
    for k in ("episode_index", "frame_index"):
        if k not in probe:
            raise ValueError(f"dataset: items have no {k!r}; ForceAugment needs 'episode_index' and 'frame_index' per item")


def episode_source(dataset) -> tuple[EpisodeDataset | None, np.ndarray | None]:
    """The EpisodeDataset behind ``dataset`` (itself or an ``EpisodeSubset`` of one) and the subset's indices.
    Those are read directly, skipping the tactile frames the cache replaces."""
    if isinstance(dataset, EpisodeDataset):
        return dataset, None
    if isinstance(dataset, EpisodeSubset) and isinstance(dataset.dataset, EpisodeDataset):
        return dataset.dataset, np.asarray(dataset.indices, np.int64)
    return None, None


def index_columns(dataset, n: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(episode_index, frame_index) of every item without reading images, where the dataset can tell:
    ``frame_table()`` (ours), or LeRobot's ``hf_dataset`` columns (row i is item i); None otherwise."""
    if isinstance(dataset, FrameTable):
        eps, frames = dataset.frame_table()
        return np.asarray(eps, np.int64), np.asarray(frames, np.int64)
    hf = getattr(dataset, "hf_dataset", None)
    if hf is None:
        return None
    try:
        eps = np.array([int(v) for v in hf["episode_index"]], np.int64)
        frames = np.array([int(v) for v in hf["frame_index"]], np.int64)
    except (KeyError, TypeError, ValueError, IndexError):
        return None
    if len(eps) != n or len(frames) != n:
        return None
    for i in {0, n - 1}:  # the columns must describe the items (a filtered view would not)
        if episode_frame(dataset[i]) != (int(eps[i]), int(frames[i])):
            return None
    return eps, frames
