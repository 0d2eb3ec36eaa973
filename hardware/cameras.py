"""Cameras and GelSight Mini through OpenCV, each with a reader thread that keeps the newest frame.

``OpenCVFrameSource`` opens a V4L2 device (by ``/dev/videoN``, by index, or by a name fragment looked
up under ``/dev/v4l/by-id``) or a video file (replay, tests), crops a border fraction, resizes to
(H, W), converts BGR -> RGB and stamps each frame with the clock. When the capture stops delivering
(device unplugged, end of a file) or the newest frame is older than ``max_age_s``, ``latest`` raises
:class:`~hardware.interfaces.SensorError` saying so. ``GelSightMini`` adds the usual 15 % border crop,
240 x 320 output, a no-contact background averaged over the first frames, and residuals with the 127
offset (``controltac_il.tactile.residual.to_residual``).

Stamps, ages, the playback rate of a video file and the waits for a frame follow the injected
:class:`~hardware.interfaces.Clock` (the wall clock by default). The reader thread is attached to it, so
with a :class:`~hardware.interfaces.VirtualClock` a file plays frame by frame in virtual time and a
test that attaches its own thread sees every frame, exactly stamped, without sleeping.
"""

from __future__ import annotations

import glob
import os
import re
import threading
import time  # perf_counter only: per-frame processing time, a measurement

import cv2
import numpy as np

from controltac_il.tactile.residual import to_residual
from hardware.interfaces import Clock, Frame, FrameSource, SensorError, WallClock

BY_ID_DIR = "/dev/v4l/by-id"


def _norm(s: str) -> str:
    return re.sub(r"[\s\-_]+", "_", s.strip().lower())


def find_video_device(name: str, by_id_dir: str = BY_ID_DIR) -> str:
    """Device node (e.g. /dev/video2) of the capture interface whose by-id name contains ``name``.

    Spaces, hyphens and underscores compare equal, case is ignored (``"GelSight Mini"`` matches
    ``usb-GelSight_GelSight_Mini_R0B_...-video-index0``); only ``video-index0`` entries count (the others
    are metadata nodes). Raises SensorError when none or several devices match.
    """
    entries = sorted(glob.glob(os.path.join(by_id_dir, "*")))
    hits = [e for e in entries if _norm(name) in _norm(os.path.basename(e)) and e.endswith("index0")]
    if not hits:
        found = ", ".join(os.path.basename(e) for e in entries) or "nothing"
        raise SensorError(f"no video device whose name contains {name!r} under {by_id_dir} (found: {found})")
    if len(hits) > 1:
        raise SensorError(
            f"several video devices match {name!r}: {', '.join(os.path.basename(h) for h in hits)}; "
            "use a longer name fragment (e.g. with the serial number) or the /dev/videoN path"
        )
    return os.path.realpath(hits[0])


def crop_and_resize(bgr: np.ndarray, crop_fraction: float, size: tuple[int, int]) -> np.ndarray:
    """Remove ``crop_fraction`` of the height and of the width from every side, resize to ``size`` (H, W),
    BGR -> RGB. Returns uint8 (H, W, 3)."""
    h, w = bgr.shape[:2]
    dy, dx = int(round(h * crop_fraction)), int(round(w * crop_fraction))
    core = bgr[dy:h - dy, dx:w - dx]
    if core.shape[:2] != tuple(size):
        core = cv2.resize(core, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(core, cv2.COLOR_BGR2RGB)


class OpenCVFrameSource(FrameSource):
    """Camera or video file read by a background thread; ``latest()`` returns the newest frame.

    name: observation name. device: ``/dev/videoN``, an integer index, a name fragment under
    /dev/v4l/by-id, or a video file path. size: output (H, W). crop_fraction: fraction of each side
    removed before resizing (0 <= f < 0.5). fps: requested camera rate (files play at their own rate).
    max_age_s: ``latest`` raises when the newest frame is older than this (None = never; the control
    loop's watchdog also checks ages). loop_file: restart a video file at its end instead of failing.
    open_timeout_s: wait for the first frame in ``start`` (clock seconds). clock: time of the stamps,
    the ages, the file's playback and the waits (default: the wall clock).
    """

    POLL_S = 0.002  # on a virtual clock, waits for a frame check every this many clock seconds

    def __init__(self, name: str, device: str | int, size: tuple[int, int] = (240, 320), crop_fraction: float = 0.0,
                 fps: float | None = None, max_age_s: float | None = None, loop_file: bool = False,
                 open_timeout_s: float = 5.0, clock: Clock | None = None):
        if len(size) != 2 or min(size) < 1:
            raise ValueError(f"size must be (H, W) with positive integers, got {size!r}")
        if not 0.0 <= crop_fraction < 0.5:
            raise ValueError(f"crop_fraction must be in [0, 0.5), got {crop_fraction!r}")
        if max_age_s is not None and not max_age_s > 0:
            raise ValueError(f"max_age_s must be a positive number of seconds or None, got {max_age_s!r}")
        self.name, self.device, self.size = name, device, (int(size[0]), int(size[1]))
        self.crop_fraction, self.fps, self.max_age_s = float(crop_fraction), fps, max_age_s
        self.loop_file, self.open_timeout_s = loop_file, open_timeout_s
        self.clock = clock or WallClock()
        self.background = None
        self.process_s: list[float] = []  # per-frame crop + resize + convert time (wall s)
        self._cap: cv2.VideoCapture | None = None
        self._latest: Frame | None = None
        self._error: str | None = None
        self._lock = threading.Lock()
        self._new_frame = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.is_file = isinstance(device, str) and os.path.isfile(device)

    def _open(self) -> cv2.VideoCapture:
        dev = self.device
        if self.is_file:
            return cv2.VideoCapture(dev)
        if isinstance(dev, str) and not dev.startswith("/dev/") and not dev.isdigit():
            dev = find_video_device(dev)
        cap = cv2.VideoCapture(int(dev) if isinstance(dev, str) and dev.isdigit() else dev, cv2.CAP_V4L2)
        if self.fps:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        return cap

    def start(self) -> None:
        """Open the capture, start the reader thread and wait for the first frame."""
        self._cap = self._open()
        if not self._cap.isOpened():
            raise SensorError(f"{self.name}: cannot open video source {self.device!r}")
        self._thread = threading.Thread(target=self._read_loop, name=f"frames-{self.name}", daemon=True)
        self.clock.attach(self._thread, follows=True)
        self._thread.start()
        self.wait_for_frame(0, self.open_timeout_s)

    def _read_loop(self) -> None:
        try:
            self._read_frames()
        finally:
            self.clock.detach()

    def _read_frames(self) -> None:
        period = 1.0 / (self._cap.get(cv2.CAP_PROP_FPS) or 30.0) if self.is_file else 0.0
        next_t, index = self.clock.now(), 0
        while not self._stop.is_set():
            ok, bgr = self._cap.read()
            if not ok and self.is_file and self.loop_file and index > 0:
                self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, bgr = self._cap.read()
            if not ok:
                with self._lock:
                    self._error = (
                        f"{self.name}: capture stopped delivering frames after {index} frames "
                        f"({'end of the video file' if self.is_file else 'device unplugged or stalled?'}: {self.device!r})"
                    )
                    self._new_frame.notify_all()
                return
            t0 = time.perf_counter()
            rgb = crop_and_resize(bgr, self.crop_fraction, self.size)
            self.process_s.append(time.perf_counter() - t0)
            index += 1
            frame = Frame(rgb, self.clock.now(), index)
            with self._lock:
                self._latest = frame
                self._new_frame.notify_all()
            if period:  # a file plays at its recorded rate, like the camera it stands in for
                next_t += period
                self.clock.wait(self._stop, max(0.0, next_t - self.clock.now()))

    def _frame_after(self, after_index: int) -> Frame | None:
        with self._lock:
            if self._error is not None:
                raise SensorError(self._error)
            return self._latest if self._latest is not None and self._latest.index > after_index else None

    def wait_for_frame(self, after_index: int, timeout_s: float) -> Frame:
        """Block until a frame newer than ``after_index`` exists; raise SensorError on failure or timeout
        (``timeout_s`` clock seconds)."""
        if not self.clock.realtime:  # sleep on the clock, so the reader thread gets the time to deliver
            deadline = self.clock.now() + timeout_s
            while (frame := self._frame_after(after_index)) is None:
                if self.clock.now() >= deadline:
                    raise SensorError(f"{self.name}: no frame from {self.device!r} within {timeout_s} s")
                self.clock.sleep_until(min(deadline, self.clock.now() + self.POLL_S))
            return frame
        with self._lock:
            ok = self._new_frame.wait_for(
                lambda: self._error is not None or (self._latest is not None and self._latest.index > after_index),
                timeout_s,
            )
            if self._error is not None:
                raise SensorError(self._error)
            if not ok:
                raise SensorError(f"{self.name}: no frame from {self.device!r} within {timeout_s} s")
            return self._latest

    def latest(self) -> Frame:
        with self._lock:
            error, frame = self._error, self._latest
        if error is not None:
            raise SensorError(error)
        if frame is None:
            raise SensorError(f"{self.name}: no frame yet (call start())")
        if self.max_age_s is not None:
            age = self.clock.now() - frame.timestamp
            if age > self.max_age_s:
                raise SensorError(f"{self.name}: newest frame is {age:.3f} s old (limit {self.max_age_s} s): stalled sensor")
        return frame

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class GelSightMini(OpenCVFrameSource):
    """GelSight Mini: 15 % border crop, 240 x 320 RGB, background averaged over ``background_frames``
    no-contact frames at start (keep the gel untouched while it starts).

    device: name fragment under /dev/v4l/by-id (default "GelSight Mini"; add the serial number when two
    sensors are plugged in), a /dev/videoN path or a video file. Other fields as OpenCVFrameSource.
    """

    def __init__(self, name: str, device: str | int = "GelSight Mini", background_frames: int = 30,
                 size: tuple[int, int] = (240, 320), crop_fraction: float = 0.15, fps: float | None = 25.0,
                 **kwargs):
        if not (isinstance(background_frames, int) and background_frames >= 1):
            raise ValueError(f"background_frames must be an integer >= 1, got {background_frames!r}")
        super().__init__(name, device, size=size, crop_fraction=crop_fraction, fps=fps, **kwargs)
        self.background_frames = background_frames

    def start(self) -> None:
        super().start()
        self.background = self.capture_background(self.background_frames)

    def capture_background(self, n: int) -> np.ndarray:
        """Mean of the next ``n`` distinct frames, uint8 (H, W, 3) (rounded)."""
        acc = np.zeros((*self.size, 3), np.float64)
        index = self.latest().index - 1
        for _ in range(n):
            frame = self.wait_for_frame(index, self.open_timeout_s)
            acc += frame.image
            index = frame.index
        return np.clip(np.rint(acc / n), 0, 255).astype(np.uint8)

    def residual(self, frame: Frame | None = None) -> np.ndarray:
        """Residual ``clip(image - background + 127)`` of ``frame`` (default: the newest), uint8 (H, W, 3)."""
        if self.background is None:
            raise SensorError(f"{self.name}: no background yet (call start())")
        return to_residual((frame or self.latest()).image, self.background)
