"""LeRobot camera plugin for the GelSight Mini: ``--robot.cameras='{gs_left: {type: gelsight_mini, device: ...}}'``.

LeRobot's ``register_third_party_plugins()`` imports this module (the distribution's name), which registers
``GelSightMiniConfig`` as camera type "gelsight_mini"; ``make_cameras_from_configs`` then finds ``GelSightMini``
(the config's class name without "Config") here. Frames are 240 x 320 RGB uint8 (H, W, 3) read by
``hardware.cameras.GelSightMini`` through :class:`~lerobot_camera_gelsight.frames.GelSightFrames`; the
no-contact background averaged at ``connect`` is the camera's ``background``.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
from lerobot.cameras import Camera, CameraConfig, ColorMode
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from hardware.interfaces import SensorError
from lerobot_camera_gelsight.frames import GelSightFrames, find_gelsight_devices

__all__ = ["GelSightMiniConfig", "GelSightMini", "GelSightFrames"]

READ_TIMEOUT_MS = 1000.0  # read(): the longest wait for a new frame (25 frames at 25 fps)


@CameraConfig.register_subclass("gelsight_mini")
@dataclass
class GelSightMiniConfig(CameraConfig):
    """A GelSight Mini as a LeRobot camera.

    device: name fragment under /dev/v4l/by-id (spaces, hyphens, underscores alike; add the serial, e.g.
    "GelSight Mini 2BKH", when two are plugged in), /dev/videoN, an index ("0") or a video file standing in.
    crop_fraction: fraction of each side removed before resizing (the sensor's dark rim). width, height:
    output px, fixed before connect (LeRobot reads the features first). fps: requested rate (Hz).
    background_frames: no-contact frames averaged at connect. background_path: also save that background as
    a PNG there (keep it outside the dataset folder). color_mode: rgb or bgr. loop_file: replay a video file.
    """

    device: str = "GelSight Mini"
    crop_fraction: float = 0.15
    fps: int = 25
    width: int = 320
    height: int = 240
    background_frames: int = 30
    background_path: str | None = None
    color_mode: ColorMode = ColorMode.RGB
    loop_file: bool = False

    def __post_init__(self) -> None:
        self.color_mode = ColorMode(self.color_mode)
        for field in ("fps", "width", "height", "background_frames"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{field} must be a positive integer, got {value!r}")
        if not 0.0 <= self.crop_fraction < 0.5:
            raise ValueError(f"crop_fraction must be in [0, 0.5), got {self.crop_fraction!r}")


class GelSightMini(Camera):
    """LeRobot ``Camera`` over :class:`GelSightFrames`: frames uint8 (height, width, 3) in ``color_mode``;
    ``background`` is the no-contact RGB image averaged at connect (None before)."""

    def __init__(self, config: GelSightMiniConfig):
        super().__init__(config)
        self.config = config
        self.frames = GelSightFrames(config.device, size=(config.height, config.width),
                                     crop_fraction=config.crop_fraction, fps=config.fps,
                                     background_frames=config.background_frames,
                                     color_order=config.color_mode.value, loop_file=config.loop_file)

    def __str__(self) -> str:
        return f"{self.__class__.__name__}({self.config.device})"

    @property
    def is_connected(self) -> bool:
        return self.frames.is_open

    @property
    def background(self) -> np.ndarray | None:
        """No-contact image averaged at connect, uint8 (height, width, 3) RGB; None before."""
        return self.frames.background

    @staticmethod
    def find_cameras() -> list[dict[str, Any]]:
        return find_gelsight_devices()

    @check_if_already_connected
    def connect(self, warmup: bool = True) -> None:
        """Open the sensor and average the background (this is the warm-up, whatever ``warmup`` says):
        keep the gel untouched while it connects. Raises ConnectionError when it delivers no frames."""
        try:
            self.frames.open(self.config.background_path)
        except SensorError as e:
            raise ConnectionError(f"{self}: {e}") from e

    @check_if_not_connected
    def read(self) -> np.ndarray:
        """The next new frame, waiting up to READ_TIMEOUT_MS; uint8 (height, width, 3)."""
        return self.frames.next_frame(READ_TIMEOUT_MS / 1e3)

    @check_if_not_connected
    def async_read(self, timeout_ms: float = 200) -> np.ndarray:
        """The newest frame not returned yet, waiting up to ``timeout_ms`` (TimeoutError after)."""
        return self.frames.next_frame(timeout_ms / 1e3)

    @check_if_not_connected
    def read_latest(self, max_age_ms: int = 500) -> np.ndarray:
        """The newest frame without waiting; TimeoutError when older than ``max_age_ms``."""
        return self.frames.newest(max_age_ms / 1e3)

    @check_if_not_connected
    def disconnect(self) -> None:
        """Stop the reader thread and release the device."""
        self.frames.close()
