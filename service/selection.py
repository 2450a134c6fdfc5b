"""Operator selection (pure): a normalised point or rectangle -> initial tracker box in pixels.

Boxes are (x, y, w, h) pixels, top-left origin. A rectangle's normalised corners are scaled by the
image size. A point becomes a square of side 2 * radius * image width centred on it (radius 0 ->
camera.default_point_radius), at least camera.min_box_px, kept inside the image. With
camera.point_proposal (the default) the box is instead the EdgeBoxes object proposal
(jsar.redetect.proposals) around the object under the click: proposals are generated for object
sides of 1/4, 1/2 and 1 x the square's (a click says where the object is, not how big), those
containing the point are scored by EdgeBoxes score x exp(-d^2), d the point's offset from the box
centre in half-sizes (an operator clicks on an object's middle), and the best wins; when no proposal
contains the point the square is used (and the caller logs which one was chosen). Either box always
contains the clicked point. Measured against the square on the shared sequences: `python -m bench.click`.
"""
from __future__ import annotations

import math

import numpy as np

from service.config import CameraConfig
from service.domain import TrackPoint, TrackRectangle

Box = tuple[float, float, float, float]
PROPOSAL_SEARCH_FACTOR = 3.0  # search square side = this * the object side hypothesis
PROPOSAL_SIDE_FRACTIONS = (0.25, 0.5, 1.0)  # object side hypotheses, fractions of the point's square side


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


def contains_point(box: Box, point: tuple[float, float]) -> bool:
    """The point (pixels) lies in the box, edges included."""
    x, y, w, h = box
    return x <= point[0] <= x + w and y <= point[1] <= y + h


def centredness(box: Box, point: tuple[float, float]) -> float:
    """exp(-d^2), d = the point's offset from the box centre in units of the box's half-sizes (1 at the
    centre, exp(-1) on an edge's midpoint, exp(-2) in a corner)."""
    x, y, w, h = box
    dx, dy = (point[0] - (x + w / 2.0)) / (w / 2.0), (point[1] - (y + h / 2.0)) / (h / 2.0)
    return math.exp(-(dx * dx + dy * dy))


def grow_to_min_side(box: Box, min_side: float, image_size: tuple[int, int]) -> Box:
    """Widen / heighten a box below min_side about its centre, then shift it back inside the image; the
    grown box holds the original, so a point inside stays inside."""
    width, height = image_size
    x, y, w, h = box
    new_w, new_h = min(max(w, min_side), float(width)), min(max(h, min_side), float(height))
    nx = min(max(x + w / 2.0 - new_w / 2.0, 0.0), width - new_w)
    ny = min(max(y + h / 2.0 - new_h / 2.0, 0.0), height - new_h)
    return (nx, ny, new_w, new_h)


def proposal_box(frame: np.ndarray, selection: TrackPoint, square: Box, min_side: float = 1.0) -> Box | None:
    """The EdgeBoxes proposal around the object under the point (see the module docstring), at least
    min_side pixels a side; None if no proposal contains the point. frame HxW[x3] uint8; square: the
    point's square (point_box), whose side scales the object size hypotheses."""
    from jsar.redetect.proposals import generate_proposals  # heavy import, only when enabled

    height, width = frame.shape[:2]
    point = (selection.x * width, selection.y * height)
    best: tuple[float, Box] | None = None
    for fraction in PROPOSAL_SIDE_FRACTIONS:
        side = max(fraction * square[2], 4.0)
        try:
            proposals = generate_proposals(frame, point, (side, side), omega=PROPOSAL_SEARCH_FACTOR)
        except ValueError:  # search region outside the image (cannot happen for a point inside it)
            continue
        for box, score in zip(proposals.boxes, proposals.scores):
            candidate = (float(box[0]), float(box[1]), float(box[2]), float(box[3]))
            if not contains_point(candidate, point):
                continue
            merit = float(score) * centredness(candidate, point)
            if best is None or merit > best[0]:
                best = (merit, candidate)
    if best is None:
        return None
    return grow_to_min_side(best[1], min_side, (width, height))


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
