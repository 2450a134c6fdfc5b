"""Evaluation metrics on hand-computed cases (OTB conventions)."""
import math

import numpy as np
import pytest

from jsar.eval import metrics

NAN = [np.nan] * 4


def test_centre_error_and_iou_hand_values():
    gt = np.array([[3, 4, 10, 10], [5, 0, 10, 10], [100, 100, 5, 5], NAN, [0, 0, 10, 10]], float)
    pred = np.array([[0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10], NAN], float)
    errors = metrics.centre_errors(pred, gt)
    assert errors[0] == pytest.approx(5.0)  # 3-4-5 triangle
    assert errors[1] == pytest.approx(5.0)
    assert math.isnan(errors[3])  # target absent: not scored
    assert errors[4] == math.inf  # no prediction: a miss
    overlaps = metrics.ious(pred, gt)
    assert overlaps[0] == pytest.approx(7 * 6 / (200 - 42))
    assert overlaps[1] == pytest.approx(50 / 150)
    assert overlaps[2] == 0.0
    assert math.isnan(overlaps[3])
    assert overlaps[4] == 0.0


def test_precision_curve_and_precision_at_20():
    errors = np.array([0.0, 5.0, 25.0, np.nan])
    curve = metrics.precision_curve(errors)
    assert curve.shape == (51,)
    assert curve[0] == pytest.approx(1 / 3)
    assert curve[4] == pytest.approx(1 / 3)
    assert curve[5] == pytest.approx(2 / 3)
    assert curve[24] == pytest.approx(2 / 3)
    assert curve[25] == pytest.approx(1.0)
    assert metrics.precision_at(errors) == pytest.approx(2 / 3)


def test_success_curve_and_auc():
    overlaps = np.array([1.0, 1 / 3, 0.0, np.nan])
    curve = metrics.success_curve(overlaps)
    assert curve.shape == (21,)
    assert curve[0] == pytest.approx(2 / 3)  # strictly greater than 0
    assert curve[6] == pytest.approx(2 / 3)  # 0.30
    assert curve[7] == pytest.approx(1 / 3)  # 0.35
    assert curve[20] == 0.0  # IoU > 1 never
    # IoU 1 beats 20 thresholds, IoU 1/3 beats 7 (0..0.30), IoU 0 none.
    assert metrics.auc(curve) == pytest.approx(27 / 63)


def test_score_skips_absent_frames_and_rejects_misaligned_input():
    gt = np.array([[0, 0, 10, 10], NAN, [10, 10, 10, 10]], float)
    pred = np.array([[0, 0, 10, 10], [50, 50, 10, 10], [10, 10, 10, 10]], float)
    result = metrics.score(pred, gt)
    assert result["frames_scored"] == 2
    assert result["precision"] == 1.0
    assert result["auc"] == pytest.approx(20 / 21)
    with pytest.raises(ValueError, match="predicted boxes but"):
        metrics.score(pred[:2], gt)
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        metrics.ious(np.zeros((3, 3)), gt)
    assert np.all(np.isnan(metrics.precision_curve(np.array([np.nan]))))


def test_divergence_finds_the_first_frame_where_two_trackers_part():
    from jsar.eval.compare import divergence

    gt = np.array([[0, 0, 10, 10]] * 4, float)
    a = gt.copy()
    b = gt.copy()
    b[2:] = [20, 20, 10, 10]
    d = divergence(a, b, gt)
    assert d["first_apart"] == 2 and d["frames_apart"] == 2
    assert d["a_better"] == 2 and d["b_better"] == 0


def test_frame_time_stats_leave_out_init_and_crashed_frames():
    from jsar.eval.evaluate import frame_time_stats
    seconds = np.array([5.0] + [0.010] * 98 + [0.100, np.nan])  # init 5 s, one slow update, a crash
    stats = frame_time_stats(seconds)
    assert stats["frame_ms_p50"] == pytest.approx(10.0)
    assert stats["frame_ms_max"] == pytest.approx(100.0)
    assert 10.0 < stats["frame_ms_p99"] < 100.0
    assert stats["frame_ms_p99_over_p50"] == pytest.approx(stats["frame_ms_p99"] / 10.0)
    assert np.isnan(frame_time_stats(np.array([1.0]))["frame_ms_p50"])


def test_timeline_codes_say_what_the_tracker_reported_and_where_the_box_was():
    from jsar.eval.report import timeline_codes
    states = ["tracking", "tracking", "lost", "recovered", "tracking"]
    on_target = np.array([True, False, False, True, False])
    visible = np.array([True, True, False, True, False])
    assert timeline_codes(states, on_target, visible) == ["on", "off", "lost", "recovered", "absent"]


def test_boxes_written_as_json_read_back_with_nan_where_null(tmp_path):
    import json

    from jsar.eval import report
    boxes = np.array([[1.0, 2.0, 3.0, 4.0], [np.nan] * 4, [5.0, 6.0, np.inf, 8.0]])
    report.write_json({"boxes": boxes}, tmp_path / "r.json")
    rows = json.loads((tmp_path / "r.json").read_text())["boxes"]
    assert rows[1] == [None] * 4  # strict JSON: NaN and inf written as null
    back = report.boxes_from_json(rows + [None])
    assert back.shape == (4, 4) and back[0].tolist() == [1.0, 2.0, 3.0, 4.0]
    assert np.isnan(back[1]).all() and np.isnan(back[2, 2]) and back[2, 3] == 8.0 and np.isnan(back[3]).all()
    assert report.boxes_from_json([]).shape == (0, 4)
