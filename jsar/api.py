"""Public tracker interface shared by every tracker in the package (OpenCV style init / update).

Conventions: frames are HxWx3 uint8 BGR (as cv2 reads them) or HxW uint8 grey; boxes are
(x, y, w, h) floats in pixels, top-left origin, x right, y down.
"""
from __future__ import annotations

import concurrent.futures
import math
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

Box = tuple[float, float, float, float]
TrackState = Literal["tracking", "lost", "recovered"]


@dataclass(frozen=True)
class TrackResult:
    """One frame's output: box (x, y, w, h) pixels, score = translation response peak, state."""

    box: Box
    score: float
    state: TrackState = "tracking"


class Tracker(Protocol):
    """What `jsar.create` returns: init on a frame and a box, then update frame by frame."""

    def init(self, frame: np.ndarray, box: Box) -> None: ...

    def update(self, frame: np.ndarray) -> TrackResult: ...


@runtime_checkable
class SideBoundedTracker(Tracker, Protocol):
    """A tracker whose box side sqrt(w*h) can be bounded from outside the image (jsar, jsar-re, strcf)."""

    def set_side_bounds(self, side_bounds_px: tuple[float, float] | None) -> None: ...


@runtime_checkable
class DeferringTracker(Tracker, Protocol):
    """A tracker with work it can hand to another thread (jsar-re: the verifier's deferred embeddings)."""

    def set_verifier_worker(self, worker: concurrent.futures.Executor | None) -> None: ...


def validate_frame(frame: object) -> np.ndarray:
    """Return `frame` if it is a non-empty HxW or HxWx3 uint8 array, else raise ValueError."""
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise ValueError(f"frame must be uint8, got dtype {frame.dtype}")
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)):
        raise ValueError(f"frame must be HxW or HxWx3, got shape {frame.shape}")
    if frame.shape[0] < 1 or frame.shape[1] < 1:
        raise ValueError(f"frame is empty: shape {frame.shape}")
    return frame


def validate_box(box: object, frame_shape: tuple[int, ...]) -> Box:
    """Return `box` as four floats if finite, positive-sized and overlapping the frame, else ValueError."""
    try:
        values = tuple(float(v) for v in box)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"box must be four numbers (x, y, w, h), got {box!r}") from exc
    if len(values) != 4:
        raise ValueError(f"box must be four numbers (x, y, w, h), got {len(values)} values")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"box has a non-finite value: {values}")
    x, y, w, h = values
    if w <= 0 or h <= 0:
        raise ValueError(f"box size must be positive, got w={w}, h={h}")
    height, width = frame_shape[:2]
    if x >= width or y >= height or x + w <= 0 or y + h <= 0:
        raise ValueError(f"box {values} does not overlap the {width}x{height} frame")
    return (x, y, w, h)
