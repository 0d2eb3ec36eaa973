"""Reads and writes the mp4 files of a LeRobot v3.0 folder with PyAV.

Reading (``VideoFrames``): frames of video files (many episodes back to back), decoded as LeRobot's ``pyav``
backend does: the frame whose presentation time is within ``tolerance_s`` (strictly, default 1e-4 s)
of the query time, converted to RGB (``rgb24``).

Per process, one open container per file (at most ``MAX_OPEN`` files, least recently used closed first). A
stream remembers where its decoder stands: a query ahead of it by at most one keyframe interval (the longest
seen so far, at least ``FORWARD_FRAMES`` frames) is decoded forward without seeking; any other query seeks to
the keyframe at or before it. The last ``keep`` frames converted are kept, so overlapping windows of
consecutive items decode each frame once. Containers are closed on pickling (DataLoader workers) and are
never used across a fork (reopened when the process id changes). Decoders and the RGB conversion run
single-threaded (DataLoader workers are the parallelism): a threaded FFmpeg decoder or swscale context
inherited by a forked worker deadlocks when that worker frees it (``avpriv_slicethread_free``; seen with h264,
libdav1d and PyAV 18's reformatter). A file FFmpeg cannot open or decode is refused in one line naming it
(``readable_video``).

Writing (``encode_video``): a source's codec (``ENCODERS``), ``decode_video`` to read a written file back whole.
"""

from __future__ import annotations

import os
from collections import OrderedDict, deque
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from controltac_il.io import atomic_path

TOLERANCE_S = 1e-4  # LeRobot's default tolerance_s: |frame time - query time| < this, in s
MAX_OPEN = 16  # open video files per process and reader
FORWARD_FRAMES = 2  # decode forward instead of seeking for gaps up to this many frames (at least)
# conversion to RGB as LeRobot's frame.to_rgb(), single-threaded (PyAV >= 17 starts swscale threads unless told)
RGB = {"format": "rgb24", **({"threads": 1} if int(av.__version__.split(".")[0]) >= 17 else {})}
# encoder and settings per source codec: LeRobot's g=2 (a keyframe every 2 frames) and SVT-AV1 preset 12, a lower
# crf than its 30 as generated frames are encoded once more after the generator's own error (round trip measured
# per write; preset 8 costs twice the time for a round trip MSE 4 % lower on the scene's 120x160 frames)
ENCODERS = {"av1": ("libsvtav1", {"crf": "10", "g": "2", "preset": "12"}),
            "h264": ("libx264", {"crf": "10", "g": "2"}),
            "hevc": ("libx265", {"crf": "10", "g": "2"})}
FALLBACK = "h264"  # a source codec without an encoder here (or none known) is written as this


class FrameTimestampError(ValueError):
    """No frame of the video lies within the tolerance of a query time (LeRobot raises the same)."""


@contextmanager
def readable_video(path: Path):
    """FFmpeg's errors opening or decoding the video ``path`` as one ValueError line naming it."""
    try:
        yield
    except (av.error.FFmpegError, OSError) as exc:
        raise ValueError(f"{path} is not a readable video file ({' '.join(str(exc).split())})") from None


class _Stream:
    """One open video file: its decoder position and the last frames converted to RGB."""

    def __init__(self, path: Path, keep: int, threads: int = 1):
        self.path = path
        with readable_video(path):
            self.container = av.open(str(path), metadata_errors="ignore")
        if not self.container.streams.video:
            self.container.close()
            raise ValueError(f"{path} is not a readable video file (no video stream)")
        self.stream = self.container.streams.video[0]
        self.stream.codec_context.thread_count = threads  # 1: freeing the decoder after a fork cannot hang
        rate = self.stream.average_rate or self.stream.base_rate
        self.frame_s = float(1 / rate) if rate else 0.0
        self.frames = None  # decode iterator; None: the next query seeks
        self.position = None  # time (s) of the last frame decoded from ``frames``
        self.gop_s = 0.0  # longest keyframe interval seen, s
        self.last_key = None  # time (s) of the last keyframe seen
        self.landed = None  # time (s) of the first frame decoded after the last seek
        self.recent = deque(maxlen=keep)  # (time s, uint8 (H, W, 3))
        self.seeks = 0

    def close(self) -> None:
        self.container.close()

    def _seek(self, t: float) -> None:
        offset = round(max(t, 0.0) / self.stream.time_base)
        self.container.seek(offset, backward=True, any_frame=False, stream=self.stream)
        self.frames, self.position, self.last_key, self.landed = self.container.decode(self.stream), None, None, None
        self.seeks += 1

    def _cached(self, t: float, tol: float):
        return next((img for s, img in self.recent if abs(s - t) < tol), None)

    def _ahead(self, t: float, tol: float) -> bool:
        """Whether ``t`` can be reached by decoding forward from the current position."""
        if self.frames is None or self.position is None or t < self.position - tol:
            return False
        return t - self.position <= max(self.gop_s, FORWARD_FRAMES * self.frame_s) + tol

    def frame(self, t: float, tol: float) -> np.ndarray:
        """uint8 (H, W, 3) RGB of the frame within ``tol`` s of time ``t`` (s)."""
        hit = self._cached(t, tol)
        if hit is not None:
            return hit
        with readable_video(self.path):
            nearest = self._find(t, tol)
        if nearest is None or abs(nearest[0] - t) >= tol:
            got = "the end of the video" if nearest is None else f"the nearest frame at {nearest[0]:.6f} s"
            raise FrameTimestampError(f"{self.path}: no frame within {tol} s of {t:.6f} s ({got})")
        return nearest[1]

    def _find(self, t: float, tol: float):
        """The first frame at or after ``t - tol`` (``_advance``), seeking where decoding forward cannot reach it."""
        if self._ahead(t, tol):
            return self._advance(t, tol)
        self._seek(t)
        nearest = self._advance(t, tol)
        if self.landed is not None and self.landed > t + tol and t > 0:
            self._seek(0.0)  # the seek landed past t (an odd index): decode from the start
            nearest = self._advance(t, tol)
        return nearest

    def _advance(self, t: float, tol: float):
        """Decode up to the first frame at or after ``t - tol``: (its time s, uint8 (H, W, 3) RGB); None at the
        end of the video."""
        for frame in self.frames or ():
            if frame.pts is None:
                continue
            s = float(frame.pts * frame.time_base)
            if self.position is None:
                self.landed = s
            if frame.key_frame:
                if self.last_key is not None:
                    self.gop_s = max(self.gop_s, s - self.last_key)
                self.last_key = s
            self.position = s
            if s >= t - tol:
                image = frame.to_ndarray(**RGB)
                self.recent.append((s, image))
                return s, image
        self.frames = None
        return None


class VideoFrames:
    """Per-process frame source over video files: ``frames(path, times) -> uint8 (T, H, W, 3)``.

    Args:
        keep: decoded frames kept per file (the longest window of a video key, plus one).
        tolerance_s: largest distance between a query time and a frame's time, s (strict, as LeRobot).
        threads: decoder threads per file (1, the default, is safe in forked DataLoader workers; 0 = FFmpeg's
            choice, for a process that never forks while decoding, e.g. the LeRobot writer).
    """

    def __init__(self, keep: int = 2, tolerance_s: float = TOLERANCE_S, threads: int = 1):
        self.keep, self.tolerance_s, self.threads = max(int(keep), 1), float(tolerance_s), int(threads)
        self._streams: OrderedDict[Path, _Stream] = OrderedDict()
        self._pid = os.getpid()

    @property
    def seeks(self) -> int:
        """Seeks made by the files open now (sequential reading makes few)."""
        return sum(s.seeks for s in self._streams.values())

    def _stream(self, path: Path) -> _Stream:
        if self._pid != os.getpid():  # a forked worker: the parent's decoders are not ours
            self._streams, self._pid = OrderedDict(), os.getpid()
        stream = self._streams.pop(path, None) or _Stream(path, self.keep, self.threads)
        self._streams[path] = stream
        while len(self._streams) > MAX_OPEN:
            self._streams.popitem(last=False)[1].close()
        return stream

    def frames(self, path: Path, times) -> np.ndarray:
        """uint8 (T, H, W, 3) RGB frames at ``times`` (s, in the file's time line), in the order given."""
        stream = self._stream(Path(path))
        found = {t: stream.frame(t, self.tolerance_s) for t in sorted({float(t) for t in times})}
        return np.stack([found[float(t)] for t in times])

    def close(self) -> None:
        """Close every open file (they reopen on the next query)."""
        if self._pid == os.getpid():
            for stream in self._streams.values():
                stream.close()
        self._streams = OrderedDict()

    def __getstate__(self):
        self.close()  # a pickled copy (a DataLoader worker) opens its own files
        return {"keep": self.keep, "tolerance_s": self.tolerance_s, "threads": self.threads}

    def __setstate__(self, state):
        self.__init__(**state)


def video_codec(path: Path) -> tuple[str, str]:
    """(codec name as the stream reports it, pix_fmt) of an mp4's first video stream."""
    with readable_video(path), av.open(str(path), metadata_errors="ignore") as container:
        ctx = container.streams.video[0].codec_context
        return ctx.name, ctx.pix_fmt or "yuv420p"


def encoder_for(codec: str) -> tuple[str, str, dict]:
    """(codec written, encoder, options) for a source ``codec``: the same where an encoder is here, else FALLBACK."""
    name = codec if codec in ENCODERS and ENCODERS[codec][0] in av.codecs_available else FALLBACK
    encoder, options = ENCODERS[name]
    return name, encoder, dict(options)


def encode_video(path: Path, frames: np.ndarray, fps: int, codec: str, pix_fmt: str = "yuv420p") -> str:
    """Encode RGB uint8 (T, H, W, 3) as an mp4, frame k at k / fps s; returns the codec written."""
    name, encoder, options = encoder_for(codec)
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only, not its banner per file
    with atomic_path(path, ".mp4") as tmp, av.open(str(tmp), "w", format="mp4") as container:
        stream = container.add_stream(encoder, rate=fps)
        stream.height, stream.width = frames.shape[1:3]
        stream.pix_fmt, stream.options = pix_fmt, options
        for k, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts, frame.time_base = k, Fraction(1, fps)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return name


def decode_video(path: Path) -> np.ndarray:
    """Every frame of an mp4's first video stream, RGB uint8 (T, H, W, 3), in presentation order."""
    with readable_video(path), av.open(str(path), metadata_errors="ignore") as container:
        container.streams.video[0].thread_type = "AUTO"  # no fork follows: FFmpeg's threads are safe here
        frames = [(f.pts, f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]
    return np.stack([img for _, img in sorted(frames, key=lambda x: x[0])])
