"""Render docs/front.png, the README's picture: one reference tactile frame and the shipped generator's frames
of the same contact at three force changes ΔFz.

    python docs/make_front_picture.py            # writes docs/front.png (atomically), about 15 s on one core

The reference is a frame of the project's own sensor model (``controltac_il.tactile.TactileSensor``, GelSight
Mini settings, 240×320, over the shipped real GelSight Mini background from NormalFlow, MIT): no real contact
frame may be shipped (the real GelSight Mini presses in ../shared/data are GPL-3.0, for measuring only). The
object, ``t_shape``, is one of the six the generator never trained on. Deterministic: same seeds, one torch
thread.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

OUT = Path(__file__).resolve().parent / "front.png"
OBJECT, POSE, REFERENCE_FZ = "t_shape", (0.0, 0.0, 0.4), 5.0  # pose: x, y mm, θ rad; force N
DELTAS = (-2.0, 2.0, 5.0)  # ΔFz, N: targets 3, 7 and 10 N, all inside the validated range [1, 10] N
SCALE = 0.75  # each panel 180×240 px, so the PNG stays small


def panel(rgb: np.ndarray, text: str) -> np.ndarray:
    h, w = rgb.shape[:2]
    out = cv2.resize(rgb, (round(w * SCALE), round(h * SCALE)), interpolation=cv2.INTER_AREA)
    band = np.full((22, out.shape[1], 3), 255, np.uint8)
    cv2.putText(band, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([band, out])


def render() -> np.ndarray:
    import torch

    from controltac_il.generator import ForceGenerator
    from controltac_il.tactile import SensorSpec, TactileSensor

    torch.set_num_threads(1)
    sensor = TactileSensor(SensorSpec.gelsight_mini())
    reference = sensor.press(OBJECT, POSE, (0.0, 0.0, REFERENCE_FZ), noise_seed=0).image
    gen = ForceGenerator.from_pretrained()  # the shipped default
    deltas = np.array([[0.0, 0.0, d] for d in DELTAS], np.float32)
    refs = np.repeat(reference[None], len(DELTAS), axis=0)
    ref_force = np.repeat(np.array([[0.0, 0.0, REFERENCE_FZ]], np.float32), len(DELTAS), axis=0)
    frames = gen.generate_images(refs, sensor.background, deltas, reference_force=ref_force, out_of_range="error")
    cells = [panel(reference, f"reference (sensor model), Fz {REFERENCE_FZ:g} N")]
    cells += [panel(f, f"generated, dFz {d:+g} N") for f, d in zip(frames, DELTAS)]
    gap = np.full((cells[0].shape[0], 4, 3), 255, np.uint8)
    return np.hstack([c if i == 0 else np.hstack([gap, c]) for i, c in enumerate(cells)])


def main() -> int:
    from controltac_il.tactile.sheet import save_png  # atomic: a temporary file renamed onto OUT

    save_png(OUT, render())
    print(f"{OUT.relative_to(OUT.parents[1])}: {OUT.stat().st_size // 1024} KB")
    return 0


if __name__ == "__main__":
    from controltac_il.cli import guard

    sys.exit(guard("docs/make_front_picture.py", main))
