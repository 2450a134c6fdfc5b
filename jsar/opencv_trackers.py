"""OpenCV's CSRT / KCF trackers behind the project's Tracker protocol (jsar.api).

They are the evaluation's baselines and a working tracker for the service and the simulator while
the JSAR tracker is written. Boxes are (x, y, w, h) pixels, top-left origin, like everywhere else.
OpenCV's modern trackers take and return integer rectangles, so boxes are rounded to whole pixels.
cv2.legacy's MOSSE is not offered: in the pinned OpenCV 5.0 wheel it reports failure on every
update after init, on real and synthetic sequences alike.
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from jsar.api import Box, TrackResult, validate_box, validate_frame


def rounded_rect(box: Box) -> tuple[int, int, int, int]:
    """(x, y, w, h) floats -> integer pixels; size rounded but at least 1 px."""
    x, y, w, h = box
    return (int(round(x)), int(round(y)), max(1, int(round(w))), max(1, int(round(h))))


def as_bgr(frame: np.ndarray) -> np.ndarray:
    """HxW grey or HxWx3 BGR uint8 -> HxWx3 BGR uint8 (OpenCV's trackers expect three channels)."""
    return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame


class OpenCVTracker:
    """An OpenCV tracker adapted to init / update -> TrackResult.

    score is 1.0 when OpenCV reports success and 0.0 when it reports failure (OpenCV exposes no
    response peak); on failure state is "lost" and box is the last box OpenCV reported as good.
    """

    def __init__(self, name: str, factory: Callable[[], object]) -> None:
        self.name = name
        self._factory = factory
        self._tracker: object | None = None
        self._last_box: Box | None = None

    def init(self, frame: np.ndarray, box: Box) -> None:
        """Start tracking `box` (x, y, w, h pixels) on `frame` (HxW or HxWx3 uint8)."""
        frame = validate_frame(frame)
        box = validate_box(box, frame.shape)
        tracker = self._factory()
        try:
            tracker.init(as_bgr(frame), rounded_rect(box))  # type: ignore[attr-defined]
        except cv2.error as exc:
            # CSRT asserts on frames or boxes a few pixels across (a 7x5 frame, a 1-px-wide box: bench/fuzz.py's
            # odd-size Zenoh frames); the API's contract for input it cannot take is a ValueError
            raise ValueError(f"{self.name}: OpenCV cannot start on a {frame.shape[1]}x{frame.shape[0]} frame with "
                             f"box {rounded_rect(box)}: {str(exc).strip().splitlines()[-1]}") from exc
        self._tracker = tracker
        self._last_box = box

    def update(self, frame: np.ndarray) -> TrackResult:
        """Track one frame; on OpenCV failure keep the last good box and report "lost"."""
        if self._tracker is None or self._last_box is None:
            raise RuntimeError(f"{self.name}: update() called before init()")
        frame = validate_frame(frame)
        ok, rect = self._tracker.update(as_bgr(frame))  # type: ignore[attr-defined]
        x, y, w, h = (float(v) for v in rect)
        if not ok or w <= 0 or h <= 0:
            return TrackResult(box=self._last_box, score=0.0, state="lost")
        self._last_box = (x, y, w, h)
        return TrackResult(box=self._last_box, score=1.0, state="tracking")


def make_csrt(**params: object) -> OpenCVTracker:
    """OpenCV CSRT (discriminative CF with channel and spatial reliability); params -> TrackerCSRT.Params."""
    def factory() -> object:
        p = cv2.TrackerCSRT.Params()
        _apply_params(p, params, "csrt")
        return cv2.TrackerCSRT.create(p)

    factory()  # fail now, not at init(), on an unknown parameter
    return OpenCVTracker("csrt", factory)


def make_kcf(**params: object) -> OpenCVTracker:
    """OpenCV KCF (kernelised correlation filter); params -> TrackerKCF.Params fields."""
    def factory() -> object:
        p = cv2.TrackerKCF.Params()
        _apply_params(p, params, "kcf")
        return cv2.TrackerKCF.create(p)

    factory()
    return OpenCVTracker("kcf", factory)


def _apply_params(target: object, params: dict[str, object], name: str) -> None:
    """Set each params entry on an OpenCV Params object; ValueError naming an unknown field."""
    for key, value in params.items():
        if key.startswith("_") or not hasattr(target, key):
            known = sorted(k for k in dir(target) if not k.startswith("_"))
            raise ValueError(f"{name}: unknown parameter {key!r}; known: {', '.join(known)}")
        setattr(target, key, value)
