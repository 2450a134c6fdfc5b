"""JSAR-Re end to end: thresholds in the tracker's own units, Algorithm 1 on a synthetic occlusion,
no retraining from scratch after a recovery, and an injected occlusion on a real sequence."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import jsar
from jsar.config import JsarParams
from jsar.redetect.jsar_re import JsarReTracker, blend_size

TARGET = 24  # px, side of the synthetic target


def _background(seed: int = 3, shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.normal(110, 30, (shape[0] // 4, shape[1] // 4, 3)).clip(0, 255).astype(np.uint8)
    return cv2.GaussianBlur(cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC), (0, 0), 1.0)


def _target() -> np.ndarray:
    patch = np.zeros((TARGET, TARGET, 3), np.uint8)
    patch[:, :] = (40, 60, 220)
    patch[6:18, 6:18] = (240, 240, 40)
    patch[10:14, :] = (20, 20, 20)
    return patch


def _frame(background: np.ndarray, top_left: tuple[int, int] | None) -> np.ndarray:
    frame = background.copy()
    if top_left is not None:
        x, y = top_left
        frame[y:y + TARGET, x:x + TARGET] = _target()
    return frame


def _path(index: int) -> tuple[int, int]:
    """Slow drift; after the absence (frames 35..44) the target comes back 75 px to the right: beyond
    the translation search square (5 * 24 px), inside the grown proposal square (5 * 1.05^10 * 24 px)."""
    x, y = 100 + index // 3, 100
    return (x + 75, y) if index >= 45 else (x, y)


def test_confidence_thresholds_separate_target_from_background_in_tracker_units():
    # zeta_e (0.0105) and zeta_s (0.013) are raw peaks in MATLAB FFT scaling: a clean self-correlation
    # peak is far above both; the same filter on background where the target was is below zeta_e.
    params = JsarParams.jsar_re()
    background = _background()
    tracker = JsarReTracker(params)
    tracker.init(_frame(background, (100, 100)), (100.0, 100.0, TARGET, TARGET))
    clean = tracker.core.locate(_frame(background, (100, 100))).peak
    empty = tracker.core.locate(background).peak
    assert clean > params.redetect_reliable_peak > params.redetect_enable_peak
    assert empty < params.redetect_enable_peak
    # Decision filter shares the first training: its peak on the clean sample is the same.
    assert tracker.decision is not None
    assert np.allclose(tracker.decision.filter_f, tracker.core.translation.filter_f)


def test_algorithm_1_on_a_synthetic_occlusion_lost_then_recovered_once():
    background = _background()
    tracker = JsarReTracker(JsarParams.jsar_re())
    tracker.init(_frame(background, _path(0)), (*map(float, _path(0)), float(TARGET), float(TARGET)))
    reinit_calls: list[int] = []
    original = tracker.core.reinitialise

    def spy(frame, box):
        reinit_calls.append(tracker.frame_index)
        original(frame, box)

    tracker.core.reinitialise = spy  # type: ignore[method-assign]
    states: dict[int, str] = {}
    boxes: dict[int, tuple[float, ...]] = {}
    for index in range(1, 70):
        visible = not 35 <= index < 45
        result = tracker.update(_frame(background, _path(index) if visible else None))
        states[index], boxes[index] = result.state, result.box
    assert all(states[i] == "tracking" for i in range(1, 35))
    lost = [i for i in range(35, 45) if states[i] == "lost"]
    assert len(lost) >= 8, states  # the monitor caught the absence (no commit onto background)
    last_confident = boxes[34]
    for i in lost:
        assert boxes[i] == last_confident  # the service can stop steering on it
    recovered = [i for i in range(45, 70) if states[i] == "recovered"]
    assert len(recovered) == 1 and recovered[0] <= 45 + 5, states
    # Re-initialised exactly once: the frames after the recovery update normally (the original's
    # never-cleared flag retrained everything from scratch on every later frame).
    assert reinit_calls == recovered
    assert all(states[i] == "tracking" for i in range(recovered[0] + 1, 70))
    x, y, w, h = boxes[69]
    tx, ty = _path(69)
    assert abs(x + w / 2 - (tx + TARGET / 2)) < 6 and abs(y + h / 2 - (ty + TARGET / 2)) < 6


def test_registry_and_parameter_errors():
    assert "jsar-re" in jsar.registry.available()
    tracker = jsar.create("jsar-re", redetect_enable_peak=0.009)
    assert isinstance(tracker, JsarReTracker) and tracker.monitor.params.enable_peak == 0.009
    with pytest.raises(ValueError, match="unknown JsarParams key"):
        jsar.create("jsar-re", omega=3)
    with pytest.raises(FileNotFoundError, match="structured-edge model file not found"):
        jsar.create("jsar-re", redetect_edge_model_path="no/such/model.yml.gz")
    with pytest.raises(RuntimeError, match="before init"):
        JsarReTracker().update(np.zeros((10, 10, 3), np.uint8))
    assert blend_size((40.0, 10.0), (10.0, 40.0), 0.5) == pytest.approx((20.0, 20.0))
