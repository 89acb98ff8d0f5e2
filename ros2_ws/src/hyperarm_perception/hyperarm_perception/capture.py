"""Frames from a camera through OpenCV's VideoCapture, with reconnection (no ROS).

``source`` is what ``cv2.VideoCapture`` opens: a V4L2 device (``/dev/video0`` or its index
``0``, opened with
the V4L2 backend and the requested size, rate and pixel format), or a video file or an image
sequence (``frames/%04d.png``), which replay a recording (``loop`` starts them again at
their end). :class:`FrameSource` never raises on a lost camera: :meth:`FrameSource.read`
returns None and the camera is reopened every ``reopen_period`` s; :attr:`FrameSource.state`
and :attr:`FrameSource.problem` say what is wrong, and :attr:`FrameSource.counts` how often.
Units: pixels, s.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from .markers import PerceptionError

__all__ = ["CaptureError", "CaptureConfig", "FrameSource", "is_device", "PIXEL_FORMATS"]

#: pixel formats a USB camera offers (FOURCC codes), "" = the camera's default
PIXEL_FORMATS = ("", "MJPG", "YUYV")


class CaptureError(PerceptionError):
    """A capture configuration that cannot work (the message names the parameter)."""


def is_device(source: str) -> bool:
    """True for a V4L2 device: a path (``/dev/video*``, ``/dev/v4l/by-id/...``) or an index
    (``0`` for /dev/video0)."""
    return source.startswith("/dev/") or source.isdigit()


@dataclass(frozen=True)
class CaptureConfig:
    """``source`` (see the module); the requested ``width`` x ``height`` (pixels, 0 = the
    camera's default), ``fps`` (frames per second, 0 = default) and ``pixel_format``
    (devices only); ``loop`` a file or sequence; ``reopen_period`` (s) between attempts to
    open a camera that is missing or lost."""

    source: str = "/dev/video0"
    width: int = 640
    height: int = 480
    fps: float = 30.0
    pixel_format: str = ""
    loop: bool = False
    reopen_period: float = 1.0

    def __post_init__(self) -> None:
        if not self.source:
            raise CaptureError("device: empty (a /dev/video* path, a video file or an image "
                               "sequence such as frames/%04d.png)")
        if self.width < 0 or self.height < 0:
            raise CaptureError(f"width/height: must be >= 0, got {self.width}x{self.height}")
        if not self.fps >= 0.0:
            raise CaptureError(f"fps: must be >= 0, got {self.fps}")
        if self.pixel_format not in PIXEL_FORMATS:
            raise CaptureError(f"pixel_format: {self.pixel_format!r} is not one of "
                               f"{', '.join(repr(p) for p in PIXEL_FORMATS)}")
        if not self.reopen_period > 0.0:
            raise CaptureError(f"reopen_period: must be > 0 s, got {self.reopen_period}")


class FrameSource:
    """One camera (see the module). ``opener`` builds the capture (tests may pass another
    OpenCV-compatible opener); ``clock`` is a monotonic clock in s."""

    def __init__(self, config: CaptureConfig,
                 opener: Callable[[str | int, int], cv2.VideoCapture] = cv2.VideoCapture,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self._opener = opener
        self._clock = clock
        self._cap: cv2.VideoCapture | None = None
        self._next_open = 0.0
        #: "closed" (not opened yet or lost), "open", "ended" (a file's end without loop)
        self.state = "closed"
        #: the last problem, a sentence ("" while frames come)
        self.problem = ""
        self.counts = {"frames": 0, "open_failures": 0, "read_failures": 0, "reopened": 0}
        self._opened_once = False

    def _open(self) -> bool:
        cfg = self.config
        backend = cv2.CAP_V4L2 if is_device(cfg.source) else cv2.CAP_ANY
        cap = self._opener(int(cfg.source) if cfg.source.isdigit() else cfg.source, backend)
        if not cap.isOpened():
            cap.release()
            self.counts["open_failures"] += 1
            self.problem = (f"cannot open {cfg.source} (missing, busy, or no permission: "
                            "is the user in the 'video' group?)" if is_device(cfg.source)
                            else f"cannot open {cfg.source} (no such file or sequence)")
            return False
        if is_device(cfg.source):
            if cfg.pixel_format:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*cfg.pixel_format))
            if cfg.width:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
            if cfg.height:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)
            if cfg.fps:
                cap.set(cv2.CAP_PROP_FPS, cfg.fps)
            # the newest frame, not one queued behind others: stamps at the read stay true
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        if self._opened_once:
            self.counts["reopened"] += 1
        self._opened_once = True
        self._cap = cap
        self.state = "open"
        self.problem = ""
        return True

    def _lose(self, problem: str) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap = None
        self.state = "closed"
        self.problem = problem
        self._next_open = self._clock() + self.config.reopen_period

    def read(self) -> np.ndarray | None:
        """The next frame (HxWx3 BGR or HxW mono uint8), or None: no camera now (it is
        reopened every ``reopen_period`` s), or a file's end (``state`` "ended")."""
        if self.state == "ended":
            return None
        if self._cap is None:
            if self._clock() < self._next_open:
                return None
            if not self._open():
                self._next_open = self._clock() + self.config.reopen_period
                return None
        assert self._cap is not None
        ok, frame = self._cap.read()
        if not ok and not is_device(self.config.source) and self.counts["frames"] > 0:
            if not self.config.loop:       # a recording's end: no more frames, no reopen
                self._cap.release()
                self._cap = None
                self.state = "ended"
                self.problem = f"{self.config.source}: end of the recording"
                return None
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._cap.read()
        if not ok or frame is None:
            self.counts["read_failures"] += 1
            self._lose(f"{self.config.source}: no frame (camera unplugged or stalled); "
                       f"reopening every {self.config.reopen_period:g} s")
            return None
        self.counts["frames"] += 1
        return frame

    def size_mismatch(self, frame: np.ndarray) -> str:
        """A sentence if ``frame`` is not the requested size ("" if it is, or none was
        requested): cameras fall back to a size they support."""
        h, w = frame.shape[:2]
        cfg = self.config
        if (cfg.width and w != cfg.width) or (cfg.height and h != cfg.height):
            return (f"{cfg.source} delivers {w}x{h}, not the requested "
                    f"{cfg.width}x{cfg.height}")
        return ""

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap = None
        self.state = "closed"
