"""How the scene moved between two frames: the camera's own motion as one image translation (pure parts).

While the target is hidden nothing of it can be followed, but the ground it was on can: a UAV camera
that pans or drifts moves the place where the target will come back. The translation of the whole
frame between consecutive frames is estimated by phase correlation (cv2.phaseCorrelate, Hann-windowed)
on small grey thumbnails. Conventions: a shift (dx, dy) is in full-frame pixels, x right, y down, the
displacement of scene content from the earlier frame to the later one (content at p moves to p + shift).
An estimate the correlation does not support (its normalised peak under `min_response`) or one too
large to be measured without aliasing (over `max_fraction` of the frame's width or height: phase
correlation measures shifts modulo the frame size) is reported as no shift.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Thumbnail:
    """A frame as the scene-motion estimate sees it: float32 grey (h, w), and full-frame px per thumbnail px."""

    grey: np.ndarray
    px_per_thumb_px: float


def thumbnail(frame: np.ndarray, side_px: int) -> Thumbnail:
    """`frame` (H, W[, 3]) uint8 averaged over k x k blocks, k the smallest whole factor that brings its
    longer side to at most side_px (cv2's area resize is several times faster by a whole factor), grey float32."""
    height, width = frame.shape[:2]
    factor = max(1, -(-max(height, width) // side_px))
    size = (max(1, width // factor), max(1, height // factor))
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
    visible = grey[: size[1] * factor, : size[0] * factor]  # whole blocks only
    small = cv2.resize(visible, size, interpolation=cv2.INTER_AREA) if factor > 1 else visible
    return Thumbnail(small.astype(np.float32), float(factor))


def scene_shift(earlier: Thumbnail, later: Thumbnail, min_response: float, max_fraction: float,
                window: np.ndarray | None = None) -> tuple[float, float]:
    """Translation (dx, dy) full-frame px of the scene from `earlier` to `later` (same size), or (0, 0)
    when the correlation peak is under min_response or the shift over max_fraction of the width / height.
    `window`: the Hann window of the thumbnails' shape (cv2.createHanningWindow), built when None."""
    if earlier.grey.shape != later.grey.shape:
        return 0.0, 0.0  # another frame size: nothing to compare
    height, width = later.grey.shape
    if height < 8 or width < 8:
        return 0.0, 0.0
    if window is None:
        window = cv2.createHanningWindow((width, height), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(earlier.grey, later.grey, window)
    if not (response >= min_response and abs(dx) <= max_fraction * width and abs(dy) <= max_fraction * height):
        return 0.0, 0.0
    return float(dx) * later.px_per_thumb_px, float(dy) * later.px_per_thumb_px
