"""Item adapters: the tactile, force and background keys of an item (our ACT HDF5 items or any dict
items, LeRobot convention), read as uint8 (H, W, 3) and written back in the layout and dtype they came in."""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Subset

from controltac_il.datasets.act_dataset import EpisodeDataset


def to_hwc_uint8(value, key: str) -> np.ndarray:
    """Tactile image of an item (tensor/array, (3, H, W) or (H, W, 3), uint8 or float in [0, 1]) -> uint8 (H, W, 3)."""
    arr = value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)
    if arr.ndim != 3 or 3 not in (arr.shape[0], arr.shape[-1]):
        raise ValueError(f"{key}: expected an RGB image (3, H, W) or (H, W, 3), got shape {arr.shape}")
    if arr.shape[0] == 3 and arr.shape[-1] != 3:
        arr = arr.transpose(1, 2, 0)
    if arr.dtype != np.uint8:
        arr = np.clip(np.round(arr.astype(np.float32) * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(arr)


def like(image: np.ndarray, original):
    """uint8 (H, W, 3) -> the original's container, layout and dtype (None: uint8 (3, H, W) tensor view)."""
    if original is None:
        return torch.from_numpy(image).permute(2, 0, 1)
    chw = original.shape[0] == 3 and original.shape[-1] != 3
    if isinstance(original, torch.Tensor):
        out = torch.from_numpy(image)
        out = out.permute(2, 0, 1) if chw else out
        return out if original.dtype == torch.uint8 else (out.to(original.dtype) / 255.0)
    arr = image.transpose(2, 0, 1) if chw else image
    return arr if original.dtype == np.uint8 else (arr.astype(original.dtype) / 255.0)


def force_key(key: str) -> str:
    """Item key of the force label (3,) N of tactile key ``key``."""
    return key.replace("tactile", "force", 1)


def background_key(key: str) -> str:
    """Item key of the no-contact background image of tactile key ``key``."""
    return key.replace("tactile", "tactile_background", 1)


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


def resolve_tactile_keys(probe: dict, wanted: tuple[str, ...] | None) -> tuple[str, ...]:
    """The item keys to augment: ``wanted`` (full keys or sensor names) or every tactile image key."""
    found = [k for k in probe if "tactile" in k and "tactile_background" not in k]
    if wanted is None:
        if not found:
            raise ValueError("tactile_keys: the items have no key containing 'tactile'; pass tactile_keys=")
        keys = tuple(found)
    else:
        keys = []
        for k in wanted:
            full = k if k in probe else f"observation.tactile.{k}"
            if full not in probe:
                raise ValueError(f"tactile_keys: unknown tactile key {k!r}; the items have {found or list(probe)}")
            keys.append(full)
        keys = tuple(keys)
    for k in keys:
        to_hwc_uint8(probe[k], k)
    return keys


def replace_image(item: dict, key: str, image: np.ndarray, target) -> None:
    """Put a generated uint8 (H, W, 3) image at ``key`` (original layout and dtype) and, where the item
    has a force label for it, set the label to the ``target`` force the image shows."""
    item[key] = like(image, item.get(key))
    fk = force_key(key)
    if fk in item:
        orig = item[fk]
        t = target.numpy() if isinstance(target, torch.Tensor) else np.asarray(target)
        if isinstance(orig, torch.Tensor):
            item[fk] = torch.from_numpy(t.astype(np.float32)).to(orig.dtype)
        else:
            item[fk] = t.astype(np.asarray(orig).dtype)


def episode_source(dataset) -> tuple[EpisodeDataset | None, np.ndarray | None]:
    """The EpisodeDataset behind ``dataset`` (itself or a ``Subset`` of one with ``frame_table``) and the
    subset's indices. Those are read directly, skipping the tactile frames the cache replaces."""
    if isinstance(dataset, EpisodeDataset):
        return dataset, None
    if isinstance(dataset, Subset) and isinstance(dataset.dataset, EpisodeDataset) and callable(
            getattr(dataset, "frame_table", None)):
        return dataset.dataset, np.asarray(dataset.indices, np.int64)
    return None, None
