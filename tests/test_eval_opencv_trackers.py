"""OpenCV trackers behind the Tracker protocol: results, lost state, input errors."""
import numpy as np
import pytest

import jsar
from jsar.eval.synthetic import synthetic_clip


@pytest.fixture(scope="module")
def clip():
    return synthetic_clip(n_frames=6, size=(120, 160), object_size=(20, 16), seed=5)


@pytest.mark.parametrize("name", ["csrt", "kcf"])
def test_follows_the_object(name, clip):
    frames, boxes = clip
    tracker = jsar.create(name)
    tracker.init(frames[0], tuple(boxes[0]))
    for frame, box in zip(frames[1:], boxes[1:]):
        result = tracker.update(frame)
        assert result.state == "tracking" and result.score == 1.0
        # KCF lags a frame at the start (object moves ~4.5 px a frame): 6 px tolerance.
        assert np.hypot(result.box[0] - box[0], result.box[1] - box[1]) < 6.0


def test_failure_reports_lost_and_keeps_the_last_good_box(clip):
    frames, boxes = clip
    tracker = jsar.create("kcf")
    tracker.init(frames[0], tuple(boxes[0]))
    good = tracker.update(frames[1])
    blank = np.zeros_like(frames[0])  # nothing to correlate with: KCF's peak falls below its threshold
    lost = tracker.update(blank)
    assert lost.state == "lost" and lost.score == 0.0
    assert lost.box == good.box


def test_grey_frames_and_input_errors(clip):
    frames, boxes = clip
    tracker = jsar.create("csrt")
    with pytest.raises(RuntimeError, match="before init"):
        tracker.update(frames[0])
    grey = frames[0][:, :, 2].copy()
    tracker.init(grey, tuple(boxes[0]))
    assert tracker.update(grey).state == "tracking"
    with pytest.raises(ValueError, match="uint8"):
        tracker.update(frames[1].astype(np.float32))
    with pytest.raises(ValueError, match="positive"):
        jsar.create("kcf").init(frames[0], (10, 10, 0, 5))
    with pytest.raises(ValueError, match="unknown parameter 'bogus'"):
        jsar.create("csrt", bogus=1)
