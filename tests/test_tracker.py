"""JsarTracker / STRCF baseline: public API, step API, hard inputs, and one real shared sequence."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import jsar
from jsar.tracking.jsar_tracker import JsarTracker, make_jsar
from tests.helpers import real_sequence


def _background(height: int, width: int, seed: int = 0) -> np.ndarray:
    """Smooth random colour clutter (uint8 HxWx3)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (max(2, height // 16), max(2, width // 16), 3)).astype(np.uint8)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)


def _draw_target(frame: np.ndarray, center: tuple[float, float], size_wh: tuple[float, float]) -> None:
    """A distinctive target: yellow box, dark cross, centred at `center` (x, y), in place."""
    x0 = int(round(center[0] - size_wh[0] / 2)); y0 = int(round(center[1] - size_wh[1] / 2))
    w = int(round(size_wh[0])); h = int(round(size_wh[1]))
    cv2.rectangle(frame, (x0, y0), (x0 + w - 1, y0 + h - 1), (0, 220, 240), -1)
    cv2.line(frame, (x0, y0 + h // 2), (x0 + w - 1, y0 + h // 2), (30, 30, 30), max(1, h // 8))
    cv2.line(frame, (x0 + w // 2, y0), (x0 + w // 2, y0 + h - 1), (30, 30, 30), max(1, w // 8))


def _sequence(shape_hw, path, size_wh, frames=12, seed=0):
    """Frames with the target moving along `path(t) -> (x, y)` centre, and the true boxes."""
    background = _background(*shape_hw, seed=seed)
    out, boxes = [], []
    for t in range(frames):
        cx, cy = path(t)
        frame = background.copy()
        _draw_target(frame, (cx, cy), size_wh)
        out.append(frame)
        boxes.append((cx - size_wh[0] / 2, cy - size_wh[1] / 2, size_wh[0], size_wh[1]))
    return out, boxes


def _track(tracker, frames, boxes):
    tracker.init(frames[0], boxes[0])
    errors = []
    for frame, truth in zip(frames[1:], boxes[1:]):
        result = tracker.update(frame)
        x, y, w, h = result.box
        errors.append(np.hypot(x + w / 2 - truth[0] - truth[2] / 2, y + h / 2 - truth[1] - truth[3] / 2))
    return errors, result


@pytest.mark.parametrize("name", ["jsar", "strcf"])
def test_tracks_a_moving_target_through_the_public_api(name):
    frames, boxes = _sequence((240, 320), lambda t: (100 + 4.5 * t, 110 + 2.0 * t), (30, 24))
    tracker = jsar.create(name)
    errors, result = _track(tracker, frames, boxes)
    assert max(errors) < 3.0
    assert result.state == "tracking" and np.isfinite(result.score) and result.score > 0
    assert all(isinstance(v, float) for v in result.box)


def test_grey_frames_use_32_channels_and_track():
    frames, boxes = _sequence((240, 320), lambda t: (120 - 3.0 * t, 100 + 3.0 * t), (28, 28))
    grey = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    tracker = make_jsar()
    errors, _ = _track(tracker, grey, boxes)
    assert tracker.last_training_sample_f.shape[0] == 32
    assert max(errors) < 3.0
    # A colour video whose channels are equal is grey too.
    tracker = make_jsar()
    tracker.init(cv2.cvtColor(grey[0], cv2.COLOR_GRAY2BGR), boxes[0])
    assert tracker.last_training_sample_f.shape[0] == 32
    colour = make_jsar()
    colour.init(frames[0], boxes[0])
    assert colour.last_training_sample_f.shape[0] == 42
    assert make_jsar(use_colour=False).params.use_colour is False


def test_tiny_six_pixel_target_keeps_its_size_and_is_tracked():
    frames, boxes = _sequence((240, 320), lambda t: (150 + 1.5 * t, 120 + 1.0 * t), (6, 7), frames=15)
    tracker = make_jsar()
    errors, result = _track(tracker, frames, boxes)
    assert max(errors) < 3.0
    assert 3.0 <= result.box[2] <= 12.0 and 3.0 <= result.box[3] <= 12.0  # not clamped to 20 px


def test_target_leaving_through_the_border_keeps_the_box_on_the_image():
    frames, boxes = _sequence((240, 320), lambda t: (30 - 3.0 * t, 120.0), (30, 30), frames=14)
    tracker = make_jsar()
    tracker.init(frames[0], boxes[0])
    for frame in frames[1:]:
        result = tracker.update(frame)
        x, y, w, h = result.box
        assert np.all(np.isfinite(result.box)) and w > 0 and h > 0
        assert -w / 2 - 1e-6 <= x <= 320 and 0 <= y + h / 2 <= 240


def test_box_touching_the_border_at_init_and_a_4k_frame():
    frames, boxes = _sequence((2160, 3840), lambda t: (3840 - 20 + 0.0 * t, 1080 + 5.0 * t), (40, 36), frames=4)
    tracker = make_jsar()
    errors, _ = _track(tracker, frames, boxes)
    assert max(errors) < 4.0


def test_invalid_frames_and_boxes_raise_clear_value_errors():
    tracker = make_jsar()
    frame = np.zeros((100, 100, 3), np.uint8)
    with pytest.raises(ValueError, match="uint8"):
        tracker.init(frame.astype(np.float32), (10, 10, 20, 20))
    with pytest.raises(ValueError, match="empty"):
        tracker.init(np.zeros((0, 100, 3), np.uint8), (10, 10, 20, 20))
    with pytest.raises(ValueError, match="shape"):
        tracker.init(np.zeros((100, 100, 4), np.uint8), (10, 10, 20, 20))
    with pytest.raises(ValueError, match="non-finite"):
        tracker.init(frame, (10, float("nan"), 20, 20))
    with pytest.raises(ValueError, match="positive"):
        tracker.init(frame, (10, 10, 0, 20))
    with pytest.raises(ValueError, match="overlap"):
        tracker.init(frame, (200, 10, 20, 20))
    with pytest.raises(ValueError, match="unknown JsarParams key"):
        jsar.create("jsar", no_such_parameter=1)
    with pytest.raises(RuntimeError, match="before init"):
        make_jsar().update(frame)
    tracker.init(frame, (10, 10, 20, 20))
    with pytest.raises(ValueError, match="uint8"):
        tracker.update(frame.astype(np.int16))


def test_locate_changes_nothing_commit_moves_and_reinitialise_retrains_once():
    frames, boxes = _sequence((240, 320), lambda t: (100 + 5.0 * t, 120.0), (30, 26), frames=8)
    tracker = make_jsar()
    tracker.init(frames[0], boxes[0])
    before = (tracker.box, tracker.translation.filter_f.copy(), tracker.size_filter.numerator.copy())
    loc = tracker.locate(frames[1])
    assert tracker.box == before[0]
    np.testing.assert_array_equal(tracker.translation.filter_f, before[1])
    np.testing.assert_array_equal(tracker.size_filter.numerator, before[2])
    assert loc.centre_xy[0] == pytest.approx(105.0, abs=1.5) and loc.peak > 0
    assert loc.sample_f.shape == tracker.last_training_sample_f.shape
    tracker.commit(frames[1], loc)
    assert tracker.box[0] + tracker.box[2] / 2 == pytest.approx(105.0, abs=1.5)
    assert not np.array_equal(tracker.translation.filter_f, before[1])
    # Re-initialise on a box elsewhere: filters from scratch there, then normal (temporal) updates.
    tracker.reinitialise(frames[2], boxes[2])
    assert tracker.box == pytest.approx(boxes[2])
    fresh = tracker.translation.filter_f.copy()
    reference = make_jsar()
    reference.init(frames[2], boxes[2])
    np.testing.assert_allclose(fresh, reference.translation.filter_f, rtol=1e-4, atol=1e-6)
    result = tracker.update(frames[3])
    reference_result = reference.update(frames[3])
    assert result.box == pytest.approx(reference_result.box, abs=1e-3)
    assert tracker.translation.filter_f is not fresh


@pytest.mark.slow
def test_real_sequence_precision_above_floor(data_root):
    """OTB_Crossing (120 frames, 360x240): measured precision 1.00 / AUC 0.79; floor 0.85."""
    sequence = real_sequence(data_root, "OTB_Crossing")
    truth, files = sequence.groundtruth, sequence.frame_paths
    tracker = jsar.create("jsar")
    tracker.init(cv2.imread(str(files[0])), tuple(truth[0]))
    hits, scores = [], []
    for path, gt in zip(files[1:], truth[1:]):
        result = tracker.update(cv2.imread(str(path)))
        scores.append(result.score)
        if np.isnan(gt).any():
            continue
        x, y, w, h = result.box
        hits.append(np.hypot(x + w / 2 - gt[0] - gt[2] / 2, y + h / 2 - gt[1] - gt[3] / 2) <= 20.0)
    assert np.mean(hits) >= 0.85
    # FFT scaling convention: confident peaks sit just above the paper's JSAR-Re thresholds
    # (enable re-detection below 0.0105, reliable above 0.013); measured median 0.021.
    assert 0.013 < float(np.median(scores)) < 0.05


def test_public_helpers_for_composition_match_the_internal_samples():
    frames, boxes = _sequence((240, 320), lambda t: (120 + 2.0 * t, 110.0), (30, 26), frames=2)
    tracker = make_jsar()
    tracker.init(frames[0], boxes[0])
    loc = tracker.locate(frames[1])
    again = tracker.sample_spectrum(frames[1], (135.0, 123.0), loc.search_side)
    np.testing.assert_array_equal(again, tracker.sample_spectrum(frames[1], (135.0, 123.0), loc.search_side))
    np.testing.assert_allclose(tracker.sample_spectrum(frames[1], tracker.centre_xy, loc.search_side),
                               loc.sample_f, rtol=1e-5, atol=1e-4)
    h_cells, w_cells = tracker.target_cells()
    assert w_cells / h_cells == pytest.approx(tracker.size_wh[0] / tracker.size_wh[1])
    assert tracker.prepare(frames[1]).shape == (240, 320, 3) and tracker.feature_colour_table is not None
