"""Operator selection (pure): a normalised point or rectangle -> initial tracker box, (x, y, w, h) pixels,
top-left origin.

A point becomes a square of side 2 * radius * image width around it (radius 0: camera.default_point_radius,
at least camera.min_box_px, inside the image), or with camera.point_proposal the best-scoring EdgeBoxes
proposal holding the point near its middle (a click says where the object is, not how big); either box
contains the point. A rectangle is scaled by the image size and, with camera.rectangle_fit, replaced by the
proposal of the object inside it when it is loose and that object stands out from its surround. The rules
and their measurements (`python -m bench.click`): docs/service.md, Selection.
"""
from __future__ import annotations

import math

import numpy as np

from jsar.eval.metrics import ious
from service.config import CameraConfig
from service.domain import TrackPoint, TrackRectangle

Box = tuple[float, float, float, float]
PROPOSAL_SEARCH_FACTOR = 5.0  # a click's search square side = this * the object side hypothesis
PROPOSAL_SIDE_FRACTIONS = (0.25, 0.5, 1.0)  # object side hypotheses, fractions of the point's square side
PROPOSAL_LARGER_FRACTIONS = (2.0, 4.0)  # tried in turn only while no proposal holds the point
CENTREDNESS_POWER = 2.0  # a click's proposal merit: EdgeBoxes score * centredness ** this
SELECTION_MAX_BOXES = 300  # EdgeBoxes boxes kept per search (the re-detection keeps 30)
RECTANGLE_SIDE_FRACTIONS = (0.35, 0.5, 0.7)  # object side hypotheses, fractions of sqrt(rectangle area)
RECTANGLE_SEARCH_FACTOR = 1.2  # a rectangle's search square side = this * its longer side
RECTANGLE_CENTREDNESS_POWER = 1.0  # a rectangle's proposal merit: score * centredness on its centre ** this
RECTANGLE_SAME_IOU = 0.7  # a proposal with at least this IoU with the rectangle is the rectangle itself
CONTRAST_BINS = 4  # colour levels per channel of colour_contrast's histograms
CONTRAST_SURROUND = 2.0  # colour_contrast's surround: the box's width and height times this


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
    return grow_within(box, min_side, (0.0, 0.0, float(image_size[0]), float(image_size[1])))


def grow_within(box: Box, min_side: float, outer: Box) -> Box:
    """grow_to_min_side inside the box `outer` (x, y, w, h) instead of the image: no side grows beyond
    outer's, and the grown box is shifted back inside it; it holds the original (inside outer)."""
    ox, oy, ow, oh = outer
    x, y, w, h = box
    new_w, new_h = min(max(w, min_side), ow), min(max(h, min_side), oh)
    nx = min(max(x + w / 2.0 - new_w / 2.0, ox), ox + ow - new_w)
    ny = min(max(y + h / 2.0 - new_h / 2.0, oy), oy + oh - new_h)
    return (nx, ny, new_w, new_h)


def _edge_boxes_settings():
    """EdgeBoxes settings for a selection: the re-detection's, with SELECTION_MAX_BOXES boxes kept."""
    from jsar.redetect.proposals import EdgeBoxesSettings  # heavy import, only when enabled

    return EdgeBoxesSettings(max_boxes=SELECTION_MAX_BOXES)


def proposal_box(frame: np.ndarray, selection: TrackPoint, square: Box, min_side: float = 1.0) -> Box | None:
    """The EdgeBoxes proposal around the object under the point (see the module docstring), at least
    min_side pixels a side; None if no proposal contains the point. frame HxW[x3] uint8; square: the
    point's square (point_box), whose side scales the object size hypotheses."""
    from jsar.redetect.proposals import generate_proposals  # heavy import, only when enabled

    height, width = frame.shape[:2]
    point = (selection.x * width, selection.y * height)
    settings = _edge_boxes_settings()
    best: tuple[float, Box] | None = None
    for fraction in PROPOSAL_SIDE_FRACTIONS + PROPOSAL_LARGER_FRACTIONS:
        if best is not None and fraction in PROPOSAL_LARGER_FRACTIONS:
            break  # larger objects are only hypothesised when no proposal of the expected sizes holds the point
        side = max(fraction * square[2], min_side, 4.0)  # a smaller object would be grown to min_side anyway
        try:
            proposals = generate_proposals(frame, point, (side, side), omega=PROPOSAL_SEARCH_FACTOR, settings=settings)
        except ValueError:  # search region outside the image (cannot happen for a point inside it)
            continue
        for box, score in zip(proposals.boxes, proposals.scores):
            candidate = (float(box[0]), float(box[1]), float(box[2]), float(box[3]))
            if not contains_point(candidate, point):
                continue
            merit = float(score) * centredness(candidate, point) ** CENTREDNESS_POWER
            if best is None or merit > best[0]:
                best = (merit, candidate)
    if best is None:
        return None
    return grow_to_min_side(best[1], min_side, (width, height))


def inside_fraction(box: Box, outer: Box) -> float:
    """Fraction of box's area that lies inside outer."""
    x0, y0 = max(box[0], outer[0]), max(box[1], outer[1])
    x1, y1 = min(box[0] + box[2], outer[0] + outer[2]), min(box[1] + box[3], outer[1] + outer[3])
    return max(0.0, x1 - x0) * max(0.0, y1 - y0) / (box[2] * box[3])


def box_iou(a: Box, b: Box) -> float:
    """Intersection over union of two boxes (the evaluation's jsar.eval.metrics.ious, for one pair)."""
    return float(ious(np.array([a], dtype=np.float64), np.array([b], dtype=np.float64))[0])


def clip_box(box: Box, outer: Box) -> Box:
    """The part of box inside outer (box assumed to overlap it)."""
    x0, y0 = max(box[0], outer[0]), max(box[1], outer[1])
    x1, y1 = min(box[0] + box[2], outer[0] + outer[2]), min(box[1] + box[3], outer[1] + outer[3])
    return (x0, y0, x1 - x0, y1 - y0)


def colour_contrast(frame: np.ndarray, box: Box) -> float:
    """Chi-square distance (0 same colours .. 1 disjoint) between the colour histograms (CONTRAST_BINS levels
    per channel) of the box and of the band around it out to CONTRAST_SURROUND x its width and height, both
    clipped to the image; 0 when either is empty."""
    height, width = frame.shape[:2]
    x, y, w, h = box
    ex, ey = (CONTRAST_SURROUND - 1.0) * w / 2.0, (CONTRAST_SURROUND - 1.0) * h / 2.0
    inner = _pixel_bounds((x, y, w, h), width, height)
    outer = _pixel_bounds((x - ex, y - ey, w + 2 * ex, h + 2 * ey), width, height)
    levels = CONTRAST_BINS
    shift = 8 - int(math.log2(levels))
    patch = frame[outer[1]:outer[3], outer[0]:outer[2]]
    if patch.ndim == 2:
        patch = np.repeat(patch[:, :, None], 3, axis=2)
    codes = patch[:, :, :3].astype(np.int32) >> shift
    codes = (codes[:, :, 0] * levels + codes[:, :, 1]) * levels + codes[:, :, 2]
    inside = np.zeros(codes.shape, bool)
    inside[inner[1] - outer[1]:inner[3] - outer[1], inner[0] - outer[0]:inner[2] - outer[0]] = True
    bins = levels ** 3
    hist_in = np.bincount(codes[inside], minlength=bins).astype(np.float64)
    hist_out = np.bincount(codes[~inside], minlength=bins).astype(np.float64)
    if hist_in.sum() == 0 or hist_out.sum() == 0:
        return 0.0
    a, b = hist_in / hist_in.sum(), hist_out / hist_out.sum()
    total = a + b
    used = total > 0
    return float(0.5 * np.sum((a[used] - b[used]) ** 2 / total[used]))


def _pixel_bounds(box: Box, width: int, height: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) integer pixels of a box, clipped to the image, at least one pixel."""
    x0 = min(max(int(round(box[0])), 0), width - 1)
    y0 = min(max(int(round(box[1])), 0), height - 1)
    x1 = min(max(int(round(box[0] + box[2])), x0 + 1), width)
    y1 = min(max(int(round(box[1] + box[3])), y0 + 1), height)
    return x0, y0, x1, y1


def fitted_rectangle_box(frame: np.ndarray, rectangle: Box, camera: CameraConfig) -> tuple[Box | None, str]:
    """The object's box inside the operator's rectangle (pixels), or None to keep the rectangle, with the
    outcome: "fitted"; "no_proposal_fits" (no proposal lies inside the rectangle and covers at least
    camera.rectangle_fit_min_area_fraction of it); "not_loose" (a proposal that is the rectangle itself
    scores at least as well, or the fitted box's area is more than 1 / camera.rectangle_loose_area_ratio of
    the rectangle's: the rectangle already is the object's box); "low_contrast" (the fitted box's colours
    differ from its surround's by less than camera.rectangle_fit_min_contrast: nothing stands out). See
    the module docstring."""
    from jsar.redetect.proposals import generate_proposals  # heavy import, only when enabled

    x, y, w, h = rectangle
    if w < 2.0 or h < 2.0:
        return None, "no_proposal_fits"
    centre = (x + w / 2.0, y + h / 2.0)
    area = w * h
    settings = _edge_boxes_settings()
    best: tuple[float, Box] | None = None
    rectangle_like = 0.0  # best merit of a proposal that is the rectangle itself (IoU >= RECTANGLE_SAME_IOU)
    for fraction in RECTANGLE_SIDE_FRACTIONS:
        side = max(fraction * math.sqrt(area), camera.min_box_px, 4.0)
        omega = RECTANGLE_SEARCH_FACTOR * max(w, h) / side
        try:
            proposals = generate_proposals(frame, centre, (side, side), omega=omega, settings=settings)
        except ValueError:  # rectangle outside the image
            continue
        for box, score in zip(proposals.boxes, proposals.scores):
            candidate = (float(box[0]), float(box[1]), float(box[2]), float(box[3]))
            merit = float(score) * centredness(candidate, centre) ** RECTANGLE_CENTREDNESS_POWER
            if box_iou(candidate, rectangle) >= RECTANGLE_SAME_IOU:
                rectangle_like = max(rectangle_like, merit)
            inside = inside_fraction(candidate, rectangle)
            if (inside < camera.rectangle_fit_min_inside  # the part inside the rectangle is the box fitted
                    or inside * candidate[2] * candidate[3] < camera.rectangle_fit_min_area_fraction * area):
                continue
            if best is None or merit > best[0]:
                best = (merit, candidate)
    if best is None:
        return None, "no_proposal_fits"
    if rectangle_like >= best[0]:
        return None, "not_loose"
    box = grow_within(clip_box(best[1], rectangle), camera.min_box_px, rectangle)
    if area < camera.rectangle_loose_area_ratio * box[2] * box[3]:
        return None, "not_loose"
    if colour_contrast(frame, box) < camera.rectangle_fit_min_contrast:
        return None, "low_contrast"
    return box, "fitted"


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
