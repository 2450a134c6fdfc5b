"""EdgeBoxes object proposals around the last target position (first stage of JSAR-Re's re-detection).

Boxes are (x, y, w, h) in full-frame pixels, 0-based, top-left origin (the project's convention).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from jsar.checked import at_least, at_most_key, below_key, check_fields, checked, interval, positive
from jsar.redetect.edges import edge_maps

# Image (HxW[x3]) -> (edge magnitude 0..1, orientation radians [0, pi)), float32 HxW each.
EdgeFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class EdgeBoxesSettings:
    """cv2.ximgproc.EdgeBoxes settings (the original's values unless said) plus how the search region is prepared."""

    alpha: float = checked(0.625, interval(0, 1, low_open=True, high_open=True))  # EdgeBoxes' sliding-window step size (IoU of neighbouring windows)
    beta: float = checked(0.85, interval(0, 1, low_open=True))  # EdgeBoxes' NMS threshold (IoU)
    min_score: float = 0.01  # EdgeBoxes' minimum box score
    max_boxes: int = checked(30, at_least(1))  # proposals kept
    max_aspect_ratio: float = checked(3.0, at_least(1))  # EdgeBoxes' maximum box aspect ratio
    min_area_fraction: float = checked(0.3, positive, below_key("max_area_ratio"))  # minimum box area = this x the target's area, at least min_area_floor_px2 (the original: a fixed 1000 px^2)
    min_area_floor_px2: float = checked(16.0, positive)  # the minimum box area's floor (px^2): targets down to the monitor's smallest stay findable
    max_area_ratio: float = 3.0  # boxes larger than this x the target's area are dropped (they took most slots on clutter)
    candidate_factor: int = checked(4, at_least(1))  # EdgeBoxes is asked for this x max_boxes boxes, so max_boxes remain after that filter
    working_target_side_px: float = checked(32.0, positive)  # the region is resampled so the target's sqrt(w*h) spans about this (px)
    edge_min_mag: float = checked(0.15, interval(0, 1, high_open=True))  # EdgeBoxes' edgeMinMag (its default 0.1): gradient edges are denser; same recall, half the cost
    min_working_scale: float = checked(0.125, positive, at_most_key("max_working_scale"))  # the resampling scale's lower bound
    max_working_scale: float = 4.0  # the resampling scale's upper bound
    max_working_pixels: int = checked(256 * 256, at_least(64 * 64))  # the resampled region's area bound (px^2; a whole 1280x720 frame took 2.5 s)

    def __post_init__(self) -> None:
        check_fields(self, "EdgeBoxesSettings")


@dataclass(frozen=True)
class Proposals:
    """EdgeBoxes output: boxes float64 (N, 4) full-frame (x, y, w, h) pixels, scores float32 (N,), best first."""

    boxes: np.ndarray
    scores: np.ndarray
    region: tuple[int, int, int, int]  # searched region (x, y, w, h), integer pixels, inside the image


def search_region(centre_xy: tuple[float, float], target_wh: tuple[float, float], omega: float,
                  image_wh: tuple[int, int]) -> tuple[int, int, int, int]:
    """Square of side omega*sqrt(w*h) px centred at centre_xy, clipped to the image -> (x, y, w, h) ints.

    A square larger than the image gives the whole image. Raises ValueError if the clipped region is
    empty (centre far outside the image) or the inputs are not positive.
    """
    w, h = target_wh
    if not (w > 0 and h > 0 and omega > 0):
        raise ValueError(f"search region needs positive target size and omega, got {target_wh}, {omega}")
    image_w, image_h = image_wh
    side = omega * math.sqrt(w * h)
    x0 = max(0, int(math.floor(centre_xy[0] - side / 2)))
    y0 = max(0, int(math.floor(centre_xy[1] - side / 2)))
    x1 = min(image_w, int(math.ceil(centre_xy[0] + side / 2)))
    y1 = min(image_h, int(math.ceil(centre_xy[1] + side / 2)))
    if x1 - x0 < 3 or y1 - y0 < 3:
        raise ValueError(f"search region around {centre_xy} of side {side:.1f} px misses the {image_w}x{image_h} image")
    return (x0, y0, x1 - x0, y1 - y0)


def working_scale(target_wh: tuple[float, float], region_wh: tuple[int, int], settings: EdgeBoxesSettings) -> float:
    """Resampling factor (working px per image px): sqrt(w*h) spans working_target_side_px, clamped,
    and the region (pixels) stays within max_working_pixels."""
    scale = settings.working_target_side_px / math.sqrt(target_wh[0] * target_wh[1])
    scale = min(settings.max_working_scale, max(settings.min_working_scale, scale))
    return min(scale, math.sqrt(settings.max_working_pixels / (region_wh[0] * region_wh[1])))


def min_box_area(target_wh: tuple[float, float], settings: EdgeBoxesSettings) -> float:
    """EdgeBoxes minimum box area in image pixels^2: a fraction of the target's, with a small floor."""
    return max(settings.min_area_floor_px2, settings.min_area_fraction * target_wh[0] * target_wh[1])


def generate_proposals(frame: np.ndarray, centre_xy: tuple[float, float], target_wh: tuple[float, float],
                       omega: float, settings: EdgeBoxesSettings = EdgeBoxesSettings(),
                       edges: EdgeFunction = edge_maps) -> Proposals:
    """EdgeBoxes proposals in the omega-square around centre_xy; boxes in full-frame pixels, best first.

    frame: HxW[x3] uint8. target_wh: last confident target size (pixels). `edges` computes the edge
    and orientation maps (default: smoothed gradients; a `StructuredEdges` instance when a model file
    is configured).
    """
    image_h, image_w = frame.shape[:2]
    rx, ry, rw, rh = search_region(centre_xy, target_wh, omega, (image_w, image_h))
    scale = working_scale(target_wh, (rw, rh), settings)
    region = frame[ry:ry + rh, rx:rx + rw]
    out_w, out_h = max(3, round(rw * scale)), max(3, round(rh * scale))
    if (out_w, out_h) != (rw, rh):
        interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
        region = cv2.resize(region, (out_w, out_h), interpolation=interpolation)
    # Exact per-axis factors after rounding, to map boxes back without drift.
    scale_x, scale_y = out_w / rw, out_h / rh
    magnitude, orientation = edges(region)
    box_finder = cv2.ximgproc.createEdgeBoxes(
        alpha=settings.alpha, beta=settings.beta, minScore=settings.min_score,
        maxBoxes=settings.max_boxes * settings.candidate_factor, edgeMinMag=settings.edge_min_mag,
        maxAspectRatio=settings.max_aspect_ratio,
        minBoxArea=float(min_box_area(target_wh, settings) * scale_x * scale_y),
    )
    boxes, scores = box_finder.getBoundingBoxes(magnitude, orientation)
    if boxes is None or len(boxes) == 0:
        return Proposals(np.zeros((0, 4)), np.zeros((0,), np.float32), (rx, ry, rw, rh))
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float32).reshape(-1)
    full = np.empty_like(boxes)
    full[:, 0] = rx + boxes[:, 0] / scale_x
    full[:, 1] = ry + boxes[:, 1] / scale_y
    full[:, 2] = boxes[:, 2] / scale_x
    full[:, 3] = boxes[:, 3] / scale_y
    small_enough = full[:, 2] * full[:, 3] <= settings.max_area_ratio * target_wh[0] * target_wh[1]
    full, scores = full[small_enough], scores[small_enough]
    order = np.argsort(-scores, kind="stable")[: settings.max_boxes]
    return Proposals(full[order], scores[order], (rx, ry, rw, rh))
