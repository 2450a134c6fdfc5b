"""File source: a video file (any container OpenCV's FFMPEG backend reads) or a folder of images.

Frames are paced at the file's own frame rate by default (`realtime`), like a camera; an image
folder is paced at `source.fps`. At the end the file starts again (`loop`) or the source ends.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import numpy as np

from service.sources.base import CorruptFrame, EndOfStream, Frame, SourceError, is_complete_jpeg

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
MAX_CONSECUTIVE_BAD_READS = 5  # a video that fails this many reads in a row has ended


class FileReader:
    """Reads a video file or an image folder in order; frame ids count up across loops."""

    def __init__(self, path: str, realtime: bool = True, loop: bool = False, folder_fps: float = 30.0) -> None:
        if folder_fps <= 0:
            raise ValueError(f"folder_fps must be > 0, got {folder_fps}")
        self.path = Path(path)
        self.name = f"file:{self.path.name}"
        self.realtime = realtime
        self.loop = loop
        self.folder_fps = folder_fps
        self._capture: cv2.VideoCapture | None = None
        self._images: list[Path] = []
        self._index = 0  # position within the file / folder
        self._next_id = 0  # frame id, never reset
        self._fps = folder_fps
        self._bad_reads = 0
        self._frame_count = 0

    def open(self) -> None:
        """Open the file or list the folder; SourceError if missing, unreadable or empty."""
        self.close()
        if not self.path.exists():
            raise SourceError(f"{self.path} does not exist")
        self._index = 0
        self._bad_reads = 0
        if self.path.is_dir():
            self._images = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self._images:
                raise SourceError(f"{self.path} holds no images ({', '.join(IMAGE_SUFFIXES)})")
            self._fps = self.folder_fps
            return
        capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"cannot open video {self.path}")
        fps = capture.get(cv2.CAP_PROP_FPS)
        self._fps = fps if math.isfinite(fps) and fps > 0 else self.folder_fps
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        self._frame_count = int(count) if math.isfinite(count) and count > 0 else 0  # 0 = unknown
        self._capture = capture

    def frame_interval_s(self) -> float | None:
        return 1.0 / self._fps if self.realtime else None

    def read(self, timeout_s: float) -> Frame | None:
        """The next frame; CorruptFrame for an undecodable image, EndOfStream at the end without loop."""
        if self._images:
            return self._read_image()
        if self._capture is None:
            raise SourceError("read before open")
        ok, image = self._capture.read()
        if not ok or image is None:
            self._bad_reads += 1
            if 0 < self._frame_count <= self._index or self._bad_reads >= MAX_CONSECUTIVE_BAD_READS:
                return self._at_end()
            raise CorruptFrame(f"{self.path.name}: frame {self._index} could not be decoded")
        self._bad_reads = 0
        self._index += 1
        return self._frame(image)

    def _read_image(self) -> Frame | None:
        if self._index >= len(self._images):
            return self._at_end()
        path = self._images[self._index]
        self._index += 1
        try:
            data = path.read_bytes()
        except FileNotFoundError as exc:  # the folder (or the file) went away: reopen lists it afresh
            raise SourceError(f"{path} is gone (source removed?)") from exc
        except OSError as exc:
            raise SourceError(f"cannot read {path}: {exc.strerror}") from exc
        image = None
        truncated = path.suffix.lower() in (".jpg", ".jpeg") and not is_complete_jpeg(data)
        if not truncated:
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            self._next_id += 1  # the slot is consumed: ids stay aligned with positions in the folder
            raise CorruptFrame(f"{path.name} is a truncated JPEG (no end-of-image marker)" if truncated
                               else f"{path.name} could not be decoded")
        return self._frame(image)

    def _at_end(self) -> Frame | None:
        if not self.loop:
            raise EndOfStream(f"end of file {self.path.name} after {self._index} frames")
        if self._capture is not None:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self._index = 0
        self._bad_reads = 0
        return None

    def _frame(self, image: np.ndarray) -> Frame:
        frame = Frame(image=image, frame_id=self._next_id, capture_time_s=time.time(),
                      read_monotonic_s=time.monotonic())
        self._next_id += 1
        return frame

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
        self._images = []
