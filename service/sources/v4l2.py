"""V4L2 camera source (cv2.CAP_V4L2): device path, requested size, rate and fourcc."""
from __future__ import annotations

import os
import re
import time

import cv2

from service.sources.base import Frame, SourceError


class V4L2Reader:
    """Reads a /dev/video* device; a missing or unplugged device raises SourceError (the worker retries)."""

    def __init__(self, device: str, width: int, height: int, fps: float, fourcc: str) -> None:
        if len(fourcc) != 4:
            raise ValueError(f"fourcc must be 4 characters, got {fourcc!r}")
        self.device = device
        self.name = f"v4l2:{device}"
        self.width, self.height, self.fps, self.fourcc = width, height, fps, fourcc
        self._capture: cv2.VideoCapture | None = None
        self._next_id = 0

    def open(self) -> None:
        if not os.path.exists(self.device):
            raise SourceError(f"camera {self.device} is absent (unplugged?)")
        match = re.fullmatch(r"/dev/video(\d+)", self.device)
        capture = cv2.VideoCapture(int(match.group(1)) if match else self.device, cv2.CAP_V4L2)
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"cannot open camera {self.device} with V4L2")
        capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        capture.set(cv2.CAP_PROP_FPS, self.fps)
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # keep the driver queue short: latest frame wins
        self._capture = capture

    def frame_interval_s(self) -> float | None:
        return None  # the camera paces itself

    def read(self, timeout_s: float) -> Frame | None:
        if self._capture is None:
            raise SourceError("read before open")
        ok, image = self._capture.read()
        if not ok or image is None:
            raise SourceError(f"camera {self.device} stopped delivering frames (unplugged?)")
        frame = Frame(image, self._next_id, time.time(), time.monotonic())
        self._next_id += 1
        return frame

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
