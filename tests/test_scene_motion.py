"""The camera's motion between frames (jsar/redetect/scene.py) and how JSAR-Re's search follows it."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from jsar.config import JsarParams
from jsar.redetect.jsar_re import JsarReTracker
from jsar.redetect.params import RedetectParams
from jsar.redetect.scene import scene_shift, thumbnail
from tests.test_redetect_tracker import TARGET, _background, _centre, _paste, _redetect, _target, _target_box


def _textured(shape: tuple[int, int] = (360, 640), seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = (rng.random((shape[0] // 8, shape[1] // 8, 3)) * 255).astype(np.uint8)
    return cv2.GaussianBlur(cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC), (0, 0), 2.0)


def _translated(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Content moved by (dx, dy) px (x right, y down), borders reflected."""
    turn = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(image, turn, (image.shape[1], image.shape[0]), borderMode=cv2.BORDER_REFLECT)


def test_thumbnail_averages_whole_blocks_to_at_most_the_side_in_grey():
    frame = _textured((360, 640))
    thumb = thumbnail(frame, 100)  # 640 / 100 -> blocks of 7 px: 91 x 51
    assert thumb.grey.shape == (51, 91) and thumb.grey.dtype == np.float32 and thumb.px_per_thumb_px == 7.0
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float64)
    assert thumb.grey[3, 5] == pytest.approx(grey[21:28, 35:42].mean(), abs=0.51)  # cv2 rounds to uint8
    assert thumbnail(frame, 1000).grey.shape == (360, 640)  # never enlarged
    assert thumbnail(frame[..., 0], 100).grey.shape == (51, 91)  # a grey frame as well


@pytest.mark.parametrize("dx, dy", [(21.0, -14.0), (-35.0, 8.0), (3.0, 0.0)])
def test_scene_shift_measures_a_translation_in_full_frame_pixels(dx, dy):
    frame = _textured()
    earlier, later = thumbnail(frame, 160), thumbnail(_translated(frame, dx, dy), 160)
    found = scene_shift(earlier, later, min_response=0.1, max_fraction=0.4)
    assert math.dist(found, (dx, dy)) < 1.5, found
    back = scene_shift(later, earlier, min_response=0.1, max_fraction=0.4)
    assert math.dist(back, (-dx, -dy)) < 1.5, back


def test_scene_shift_reports_no_motion_it_cannot_measure():
    frame = _textured()
    earlier = thumbnail(frame, 160)
    # Beyond max_fraction of the height (0.4 x 360 = 144 px): phase correlation aliases there.
    assert scene_shift(earlier, thumbnail(_translated(frame, 0.0, 170.0), 160), 0.05, 0.4) == (0.0, 0.0)
    assert scene_shift(earlier, thumbnail(_translated(frame, 0.0, 170.0), 160), 0.05, 0.49) != (0.0, 0.0)
    # Two unrelated frames: no correlation peak worth the name.
    assert scene_shift(earlier, thumbnail(_textured(seed=9), 160), 0.2, 0.4) == (0.0, 0.0)
    # Another frame size: nothing to compare.
    assert scene_shift(earlier, thumbnail(_textured((300, 640)), 160), 0.0, 0.4) == (0.0, 0.0)


def test_scene_parameters_are_validated_by_name():
    for mapping, key in [({"search": {"scene_motion_px": 8}}, "redetect.search.scene_motion_px"),
                         ({"search": {"scene_min_response": 1.5}}, "redetect.search.scene_min_response"),
                         ({"search": {"scene_max_fraction": 0.5}}, "redetect.search.scene_max_fraction")]:
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            RedetectParams.from_mapping(mapping)


PAN_PX = 3  # px per frame the camera pans while the target is hidden


def _panning_camera(index: int, world: np.ndarray) -> np.ndarray:
    """Frame index -> a 240 x 320 view of `world`: the target stands still on the ground at world (260, 100),
    hidden on frames 35..59; the camera holds until frame 35, then pans so the scene moves PAN_PX px right per
    frame until frame 60 (75 px, 3.1 target sides, in all), then holds."""
    offset = 160 - PAN_PX * min(max(index - 34, 0), 25)
    scene = world.copy()
    if not 35 <= index < 60:
        _paste(scene, _target(), (260, 100))
    return np.ascontiguousarray(scene[:, offset:offset + 320])


def _run_panning(redetect: RedetectParams) -> tuple[dict[int, tuple[str, tuple]], dict[int, tuple[float, float]]]:
    world = _background(shape=(240, 520))
    tracker = JsarReTracker(JsarParams.jsar_re(), redetect)
    tracker.init(_panning_camera(0, world), _target_box((100, 100)))
    results, anchors = {}, {}
    for index in range(1, 70):
        result = tracker.update(_panning_camera(index, world))
        results[index] = (result.state, result.box)
        if tracker.search is not None:
            anchors[index] = tracker.search.anchor_xy
    return results, anchors


def test_the_search_follows_the_scene_while_the_camera_pans_over_a_hidden_target():
    """Where the target stood (image x = 112 + 3 per panned frame) is where the search looks, the lost box waits,
    and where the target is taken back the frame it shows again (60, image x 187)."""
    results, anchors = _run_panning(RedetectParams())
    assert all(results[i][0] == "tracking" for i in range(1, 35))
    assert all(results[i][0] == "lost" for i in range(36, 60)), [results[i][0] for i in range(35, 60)]
    for i in range(40, 60):  # the camera has moved the place by PAN_PX x (i - 34) px
        place = (112.0 + PAN_PX * (i - 34), 112.0)
        assert math.dist(anchors[i], place) < 4, (i, anchors[i], place)
        assert math.dist(_centre(results[i][1]), place) < 4, (i, results[i][1], place)
    assert results[60][0] == "recovered" and math.dist(_centre(results[60][1]), (187.0, 112.0)) < 4, results[60]
    assert all(results[i][0] == "tracking" and math.dist(_centre(results[i][1]), (187.0, 112.0)) < 4
               for i in range(61, 70))
    # Without it the search stays where the target was in the image, 75 px (3.1 sides) from where it shows
    # again: not taken back on the frame it shows (the scenario tests the scene's motion).
    fixed, fixed_anchors = _run_panning(_redetect(search={"scene_motion_px": 0}))
    assert math.dist(fixed_anchors[59], (112.0, 112.0)) < 4, fixed_anchors[59]
    assert fixed[60][0] == "lost", fixed[60]
