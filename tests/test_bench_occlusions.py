"""bench.occlusions: failures are counted where the car is lost for good, never where it is followed."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench import occlusions
from jsar.api import TrackResult
from sim.scene import CameraConfig, Scene, SceneConfig

SECONDS = 12.0  # one canopy, under its centre at 8 s


def small_scene() -> Scene:
    return Scene(SceneConfig(seed=3, texture="procedural", texture_size_px=512), CameraConfig())


class RedBlobTracker:
    """Finds the scene's red car by colour every frame (lost when too little of it shows): a tracker that
    cannot lose the car for good."""

    def __init__(self) -> None:
        self.inits = 0

    def init(self, frame: np.ndarray, box) -> None:
        self.inits += 1

    def update(self, frame: np.ndarray) -> TrackResult:
        b, g, r = (frame[..., k].astype(int) for k in range(3))
        mask = ((r > 150) & (r - g > 80) & (r - b > 80)).astype(np.uint8)
        if mask.sum() < 40:
            return TrackResult(box=(0.0, 0.0, 1.0, 1.0), score=0.0, state="lost")
        x, y, w, h = cv2.boundingRect(mask)
        return TrackResult(box=(float(x), float(y), float(w), float(h)), score=1.0, state="tracking")


class LostTracker:
    """Reports "lost" on every frame."""

    made = 0

    def __init__(self) -> None:
        LostTracker.made += 1

    def init(self, frame: np.ndarray, box) -> None:
        pass

    def update(self, frame: np.ndarray) -> TrackResult:
        return TrackResult(box=(0.0, 0.0, 1.0, 1.0), score=0.0, state="lost")


def test_centre_inside_is_the_box_centre_in_the_truth():
    assert occlusions.centre_inside((10, 10, 20, 20), (15, 15, 10, 10))
    assert not occlusions.centre_inside((0, 0, 10, 10), (15, 15, 10, 10))


def test_a_tracker_that_follows_the_car_through_the_canopy_never_fails():
    tracker = RedBlobTracker()
    result = occlusions.run_seed(3, SECONDS / 60.0, lambda: tracker, scene=small_scene())
    assert result.occluders == {"canopy": 1}
    assert result.failures == []
    assert tracker.inits == 1
    assert result.hidden_frames > 0  # the canopy hid most of the car for a while
    assert result.hidden_tracking_off == 0
    assert result.visible_on / result.visible_frames > 0.95


def test_a_tracker_that_never_finds_the_car_fails_every_fail_s_and_is_reset():
    LostTracker.made = 0
    result = occlusions.run_seed(3, SECONDS / 60.0, LostTracker, scene=small_scene(), fail_s=2.0)
    visible_runs = result.visible_frames // int(2.0 * occlusions.FPS)
    assert len(result.failures) == pytest.approx(visible_runs, abs=1)  # the canopy splits one run
    assert len(result.failures) >= 4
    assert LostTracker.made == len(result.failures) + 1  # a new tracker after each failure
    assert all(f.tracker_state == "lost" and f.last_event is None for f in result.failures)
    assert result.failures[0].occluder == "none" and result.failures[0].time_s == pytest.approx(1 / 30.0, abs=1e-3)
    after_canopy = [f for f in result.failures if f.time_s > 8.0]
    assert after_canopy and all(f.occluder == "canopy" for f in after_canopy)
    assert result.visible_on == 0
    assert "| 3 | 1 (1 / 0) |" in occlusions.summary([result])


class BoundedLostTracker(LostTracker):
    """A LostTracker that records the side bounds it is given."""

    bounds: list = []

    def set_side_bounds(self, bounds) -> None:
        BoundedLostTracker.bounds.append(bounds)


@pytest.mark.parametrize("band", [2.0, 0.0])
def test_each_new_tracker_gets_the_services_size_bound_around_its_initial_side(band):
    BoundedLostTracker.bounds = []
    result = occlusions.run_seed(3, 5.0 / 60.0, BoundedLostTracker, scene=small_scene(), side_band=band)
    if band == 0:
        assert BoundedLostTracker.bounds == []
        return
    assert len(BoundedLostTracker.bounds) == len(result.failures) + 1 >= 2
    for lo, hi in BoundedLostTracker.bounds:
        assert hi / lo == pytest.approx(band * band)
        assert 5.0 < lo < hi < 200.0  # about the car's side in px at the bench's range
