"""The GelSight Mini behind the LeRobot camera, without LeRobot: ``hardware.cameras.GelSightMini`` (device
by name, 15 % border crop, resize, no-contact background) answering the calls a LeRobot ``Camera`` makes
(a frame newer than the last one returned, the newest frame, its age), plus the sensors under /dev/v4l/by-id.

Frames are uint8 (H, W, 3), RGB (BGR when asked), in the sensor's own orientation: the force labels and the
augmenter work in the sensor frame (x along image columns), so nothing here rotates.
"""

from __future__ import annotations

import glob
import os

import cv2
import numpy as np

from hardware.cameras import BY_ID_DIR
from hardware.cameras import GelSightMini as GelSightReader
from hardware.interfaces import Clock, SensorError

COLOR_ORDERS = ("rgb", "bgr")


def find_gelsight_devices(by_id_dir: str = BY_ID_DIR) -> list[dict]:
    """GelSight capture interfaces plugged in: ``[{"name": by-id name, "type": "gelsight_mini", "id": /dev/videoN}]``
    (only ``video-index0`` entries: the others are metadata nodes)."""
    entries = sorted(glob.glob(os.path.join(by_id_dir, "*")))
    return [{"name": os.path.basename(e), "type": "gelsight_mini", "id": os.path.realpath(e)}
            for e in entries if "gelsight" in os.path.basename(e).lower() and e.endswith("index0")]


def save_background(image: np.ndarray, path: str) -> None:
    """Write an RGB uint8 (H, W, 3) background as a PNG at ``path``, atomically (folders made as needed): a
    stopped recording never leaves a half-written background that a later session would load."""
    from controltac_il.tactile.sheet import save_png

    try:
        save_png(path, image)
    except OSError as exc:
        raise OSError(f"background_path: cannot write a PNG at {path!r} ({exc})") from None


class GelSightFrames:
    """One GelSight Mini, or a video file standing in for it, read by ``hardware.cameras.GelSightMini``.

    device: name fragment under /dev/v4l/by-id (e.g. "GelSight Mini 2BKH"), /dev/videoN, an index or a
    video file path. size: output (H, W) px. crop_fraction: fraction of each side removed before resizing.
    fps: requested camera rate (Hz; a file plays at its recorded rate). background_frames: no-contact
    frames averaged at ``open``. color_order: "rgb" or "bgr". loop_file: restart a video file at its end.
    open_timeout_s: wait for the first frames (clock s). clock: stamps and waits (default: the wall clock).
    """

    def __init__(self, device: str | int, size: tuple[int, int] = (240, 320), crop_fraction: float = 0.15,
                 fps: float | None = 25.0, background_frames: int = 30, color_order: str = "rgb",
                 loop_file: bool = False, open_timeout_s: float = 5.0, clock: Clock | None = None):
        if color_order not in COLOR_ORDERS:
            raise ValueError(f"color_order must be one of {COLOR_ORDERS}, got {color_order!r}")
        self.color_order = color_order
        self._settings = dict(name=str(device), device=device, background_frames=background_frames, size=size,
                              crop_fraction=crop_fraction, fps=fps, loop_file=loop_file,
                              open_timeout_s=open_timeout_s, clock=clock)
        self.reader = GelSightReader(**self._settings)  # checks the settings now, not at open
        self.is_open = False
        self._used = False
        self._last_index = 0

    @property
    def background(self) -> np.ndarray | None:
        """No-contact image averaged at ``open``, uint8 (H, W, 3) RGB; None before the first open."""
        return self.reader.background

    def open(self, background_path: str | None = None) -> None:
        """Open the device and average the background (keep the gel untouched meanwhile); with
        ``background_path``, also save it there as a PNG. Raises SensorError when no frames come."""
        if self._used:  # a closed reader's thread does not restart: reopen with a new one
            self.reader = GelSightReader(**self._settings)
        self._used = True
        try:
            self.reader.start()
        except BaseException:
            self.reader.close()
            raise
        self.is_open = True
        self._last_index = self.reader.latest().index
        if background_path:
            save_background(self.background, background_path)

    def next_frame(self, timeout_s: float) -> np.ndarray:
        """The first frame newer than the last one returned, waiting up to ``timeout_s`` (clock s), uint8 (H, W, 3).

        Raises TimeoutError when none comes in time, SensorError when the capture stopped (unplugged, end of file).
        """
        try:
            frame = self.reader.wait_for_frame(self._last_index, timeout_s)
        except SensorError:
            self.reader.latest()  # raises the capture's own error when it stopped
            raise TimeoutError(f"{self.reader.name}: no new frame within {timeout_s * 1e3:.0f} ms") from None
        self._last_index = frame.index
        return self._ordered(frame.image)

    def newest(self, max_age_s: float) -> np.ndarray:
        """The newest frame, returned before or not, uint8 (H, W, 3); TimeoutError when it is older than
        ``max_age_s`` (clock s), SensorError when the capture stopped."""
        frame = self.reader.latest()
        age = self.reader.clock.now() - frame.timestamp
        if age > max_age_s:
            raise TimeoutError(
                f"{self.reader.name}: newest frame is {age * 1e3:.0f} ms old (limit {max_age_s * 1e3:.0f} ms)")
        return self._ordered(frame.image)

    def close(self) -> None:
        """Stop the reader thread and release the device."""
        self.reader.close()
        self.is_open = False

    def _ordered(self, rgb: np.ndarray) -> np.ndarray:
        return rgb if self.color_order == "rgb" else cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
