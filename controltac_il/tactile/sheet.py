"""Contact sheets: a grid of tactile images (objects × forces) saved as one PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from controltac_il.io import atomic_path
from controltac_il.tactile.sensor import TactileSensor


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def contact_sheet(sensor: TactileSensor, objects: Sequence[str], forces: Sequence[float],
                  pose=(0.0, 0.0, 0.4), seed: int = 0) -> np.ndarray:
    """Grid uint8 RGB: one row per object, one column per normal force (N), labelled."""
    rows = []
    for i, obj in enumerate(objects):
        cells = [_label(sensor.press(obj, pose, (0.0, 0.0, f), noise_seed=seed + i).image, f"{obj} {f:g} N") for f in forces]
        rows.append(np.hstack(cells))
    return np.vstack(rows)


def save_png(path, rgb: np.ndarray) -> Path:
    """Write an RGB image as PNG atomically."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")
    return path
