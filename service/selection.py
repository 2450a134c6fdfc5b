"""Operator selection (pure): a normalised point or rectangle -> initial tracker box in pixels.

Boxes are (x, y, w, h) pixels, top-left origin. A rectangle's normalised corners are scaled by the
image size. A point becomes a square of side 2 * radius * image width centred on it (radius 0 ->
camera.default_point_radius), at least camera.min_box_px, kept inside the image. With
camera.point_proposal the square is replaced by the highest-scoring EdgeBoxes object proposal
(jsar.redetect.proposals) that contains the point and whose area is within 4x of the square's; when
no proposal qualifies the square is used (and the caller logs which one was chosen).
"""
from __future__ import annotations

import math

import numpy as np

from service.config import CameraConfig
from service.domain import TrackPoint, TrackRectangle

Box = tuple[float, float, float, float]
PROPOSAL_SEARCH_FACTOR = 3.0  # search square side = this * the point's square side
PROPOSAL_MAX_AREA_RATIO = 4.0


def rectangle_box(selection: TrackRectangle, image_size: tuple[int, int]) -> Box:
    """Normalised corners -> (x, y, w, h) pixels for an image of (width, height)."""
    width, height = image_size
    return (selection.x0 * width, selection.y0 * height,
            (selection.x1 - selection.x0) * width, (selection.y1 - selection.y0) * height)


def point_box(selection: TrackPoint, image_size: tuple[int, int], camera: CameraConfig) -> Box:
    """Square around the point: side 2 * radius * width (radius 0 -> default), >= min_box_px, inside the image."""
    width, height = image_size
    radius = selection.radius if selection.radius > 0 else camera.default_point_radius
    side = min(max(2.0 * radius * width, camera.min_box_px), float(width), float(height))
    cx, cy = selection.x * width, selection.y * height
    x = min(max(cx - side / 2.0, 0.0), width - side)
    y = min(max(cy - side / 2.0, 0.0), height - side)
    return (x, y, side, side)


def proposal_box(frame: np.ndarray, selection: TrackPoint, square: Box) -> Box | None:
    """Best EdgeBoxes proposal containing the point with area within 4x of `square`; None if none qualifies."""
    from jsar.redetect.proposals import generate_proposals  # heavy import, only when enabled

    height, width = frame.shape[:2]
    px, py = selection.x * width, selection.y * height
    side = square[2]
    proposals = generate_proposals(frame, (px, py), (side, side), omega=PROPOSAL_SEARCH_FACTOR)
    square_area = side * side
    for (x, y, w, h) in proposals.boxes:  # best first
        area = w * h
        inside = x <= px <= x + w and y <= py <= y + h
        if inside and square_area / PROPOSAL_MAX_AREA_RATIO <= area <= square_area * PROPOSAL_MAX_AREA_RATIO:
            return (float(x), float(y), float(w), float(h))
    return None


def rescale_box(box: Box, old_size: tuple[int, int], new_size: tuple[int, int]) -> Box:
    """Map a box between frame sizes (same field of view, resolution changed): scale x by width, y by height."""
    sx, sy = new_size[0] / old_size[0], new_size[1] / old_size[1]
    x, y, w, h = box
    return (x * sx, y * sy, w * sx, h * sy)


def normalised_box(box: Box, image_size: tuple[int, int]) -> Box:
    """(x, y, w, h) pixels -> (x, y, w, h) as fractions of the image width / height."""
    width, height = image_size
    x, y, w, h = box
    return (x / width, y / height, w / width, h / height)


def box_is_finite(box: Box) -> bool:
    return all(math.isfinite(v) for v in box)
