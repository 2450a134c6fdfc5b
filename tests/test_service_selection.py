"""Selection boxes on synthetic frames: a loose rectangle is fitted to the object inside it (and kept when
nothing fits or it is already tight); a click on a tall thin object boxes all of it."""
from __future__ import annotations

import dataclasses
import os

os.environ.setdefault("MAVLINK20", "1")

import cv2
import numpy as np
import pytest

from service.config import CameraConfig, config_from_mapping
from service.domain import TrackPoint, TrackRectangle
from service.selection import (Box, box_iou, colour_contrast, fitted_rectangle_box, inside_fraction, point_box,
                               proposal_box)

SIZE = (320, 240)
OBJECT = (140.0, 100.0, 30.0, 20.0)  # x, y, w, h of the object drawn by _scene


def _ground(seed: int, size: tuple[int, int] = SIZE, mean: float = 90.0) -> np.ndarray:
    """Plain ground: smoothed colour noise, nothing standing out."""
    rng = np.random.default_rng(seed)
    image = rng.normal(mean, 6, (size[1], size[0], 3)).clip(0, 255).astype(np.uint8)
    return cv2.GaussianBlur(image, (0, 0), 1.0)


def _scene(seed: int) -> np.ndarray:
    """Plain ground with one 30x20 coloured object at OBJECT."""
    image = _ground(seed)
    x, y, w, h = (int(v) for v in OBJECT)
    cv2.rectangle(image, (x, y), (x + w - 1, y + h - 1), (200, 170, 60), -1)
    return image


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("rectangle", [(125.0, 88.0, 65.0, 44.0), (130.0, 80.0, 60.0, 55.0),
                                       (120.0, 92.0, 62.0, 40.0)])
def test_a_loose_rectangle_is_fitted_to_the_object_inside_it(seed: int, rectangle: Box) -> None:
    """A rectangle 4-6x the object's area, the object off its centre: the box fits the object, inside the
    rectangle (the rectangle itself overlaps the object by less than half)."""
    image = _scene(seed)
    assert box_iou(rectangle, OBJECT) < 0.5
    box, outcome = fitted_rectangle_box(image, rectangle, CameraConfig())
    assert outcome == "fitted" and box is not None
    assert box_iou(box, OBJECT) > 0.6, box
    assert inside_fraction(box, rectangle) == pytest.approx(1.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("mean", [64.0, 90.0, 128.0])
def test_a_rectangle_with_nothing_inside_is_kept(seed: int, mean: float) -> None:
    """Plain ground (noise only; 128 straddles a colour bin edge): the operator's rectangle is kept."""
    image = _ground(seed, mean=mean)
    for rectangle in [(100.0, 60.0, 80.0, 60.0), (20.0, 20.0, 40.0, 30.0), (150.0, 100.0, 20.0, 20.0)]:
        box, outcome = fitted_rectangle_box(image, rectangle, CameraConfig())
        assert box is None and outcome in ("no_proposal_fits", "not_loose", "low_contrast"), (rectangle, box)
    flat = np.full((SIZE[1], SIZE[0], 3), 90, np.uint8)
    assert fitted_rectangle_box(flat, (100.0, 60.0, 80.0, 60.0), CameraConfig()) == (None, "no_proposal_fits")


def test_a_rectangle_already_tight_on_the_object_is_kept() -> None:
    """The rectangle is the object's box (or a few pixels larger): nothing to fit, not a part of it."""
    image = _scene(0)
    for rectangle in [OBJECT, (138.0, 98.0, 34.0, 24.0)]:
        assert fitted_rectangle_box(image, rectangle, CameraConfig()) == (None, "not_loose")


def test_a_fitted_box_of_a_tiny_object_is_grown_to_min_box_px_inside_the_rectangle() -> None:
    image = _ground(3)
    cv2.rectangle(image, (150, 100), (155, 106), (220, 60, 60), -1)  # a 6x7 object
    rectangle = (146.0, 95.0, 16.0, 18.0)
    box, outcome = fitted_rectangle_box(image, rectangle, CameraConfig())
    assert outcome == "fitted" and box is not None
    assert min(box[2], box[3]) == pytest.approx(CameraConfig().min_box_px)
    assert inside_fraction(box, rectangle) == pytest.approx(1.0) and inside_fraction((150, 100, 6, 7), box) == 1.0


def test_the_fit_thresholds_are_the_configured_ones() -> None:
    """A stricter "loose" ratio keeps a rectangle the default fits; so do a contrast threshold above the
    object's and a minimum area fraction above 1 / the loose ratio (no box can then be both)."""
    image = _scene(0)
    rectangle = (125.0, 88.0, 65.0, 44.0)  # 4.8x the object's area
    assert fitted_rectangle_box(image, rectangle, CameraConfig())[1] == "fitted"
    stricter = dataclasses.replace(CameraConfig(), rectangle_loose_area_ratio=6.0)
    assert fitted_rectangle_box(image, rectangle, stricter) == (None, "not_loose")
    box, _ = fitted_rectangle_box(image, rectangle, CameraConfig())
    picky = dataclasses.replace(CameraConfig(), rectangle_fit_min_contrast=min(1.0, colour_contrast(image, box) + 0.01))
    assert fitted_rectangle_box(image, rectangle, picky) == (None, "low_contrast")
    large_only = dataclasses.replace(CameraConfig(), rectangle_fit_min_area_fraction=0.7)
    assert fitted_rectangle_box(image, rectangle, large_only)[0] is None


def test_colour_contrast_separates_an_object_from_plain_ground() -> None:
    """0 .. 1; plain ground scores near 0 (a little more when its colours straddle a histogram bin edge)."""
    assert colour_contrast(_scene(0), OBJECT) > 0.5
    assert colour_contrast(_ground(0), OBJECT) < 0.01
    assert colour_contrast(_ground(0, mean=128.0), OBJECT) < 0.05


def _pedestrian(seed: int) -> tuple[np.ndarray, Box]:
    """A 15x48 dark figure (head, torso, lighter legs) on a 360x240 frame: OTB_Crossing's pedestrian."""
    image = _ground(seed, size=(360, 240), mean=95.0)
    x, y = 200, 150
    cv2.ellipse(image, (x + 8, y + 5), (4, 5), 0, 0, 360, (40, 40, 45), -1)
    cv2.rectangle(image, (x + 1, y + 10), (x + 14, y + 29), (35, 35, 40), -1)
    cv2.rectangle(image, (x + 3, y + 30), (x + 7, y + 47), (60, 55, 55), -1)
    cv2.rectangle(image, (x + 9, y + 30), (x + 13, y + 47), (60, 55, 55), -1)
    return image, (float(x), float(y), 15.0, 48.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("height_fraction", [0.2, 0.3, 0.5])
def test_a_click_on_a_tall_thin_object_boxes_all_of_it(seed: int, height_fraction: float) -> None:
    """A click on the torso (or the middle) of a figure three times as tall as wide, in a frame whose
    default click square (0.08 x 360 = 28.8 px) is smaller than the figure: the box spans head to feet
    (before: a box of the upper body only, IoU 0.62 at 0.2 of the height)."""
    image, figure = _pedestrian(seed)
    camera = CameraConfig()
    point = (figure[0] + figure[2] / 2, figure[1] + height_fraction * figure[3])
    click = TrackPoint(point[0] / 360, point[1] / 240, 0.0)
    box = proposal_box(image, click, point_box(click, (360, 240), camera), camera.min_box_px)
    assert box is not None
    assert box_iou(box, figure) > 0.75, box
    assert box[1] <= figure[1] + 3 and box[1] + box[3] >= figure[1] + figure[3] - 3, box


class _NullOutputs:
    def apply(self, now_s: float, command: object) -> None:
        pass


@pytest.mark.parametrize("fit", [True, False])
def test_the_loop_starts_tracking_on_the_fitted_box_unless_fitting_is_off(fit: bool) -> None:
    import jsar
    from service.loop import TrackingLoop
    from service.mavlink.autopilot import AutopilotView
    from service.sources.base import Frame, LatestSlot
    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0},
                                  "camera": {"rectangle_fit": fit}})
    image = _scene(0)
    rectangle = (125.0, 88.0, 65.0, 44.0)
    selections: LatestSlot = LatestSlot()
    loop = TrackingLoop(config, selections, lambda: jsar.create("csrt"), _NullOutputs(), lambda: AutopilotView())
    x, y, w, h = rectangle
    selections.put(TrackRectangle(x / SIZE[0], y / SIZE[1], (x + w) / SIZE[0], (y + h) / SIZE[1]))
    report = loop.step(Frame(image, 0, 0.0, 0.0))
    assert report.state == "tracking"
    if fit:
        assert box_iou(report.box, OBJECT) > 0.7, report.box
    else:
        assert report.box == pytest.approx(rectangle)
