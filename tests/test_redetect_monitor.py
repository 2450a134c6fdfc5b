"""Failure monitor: confident / reliable / eligible verdicts, the reference's asymmetric update and
its freeze below the reliable band, restart, inside rules, and parameter errors that name the key."""
from __future__ import annotations

import dataclasses

import pytest

from jsar.redetect.monitor import FailureMonitor, MonitorParams, box_is_inside, updated_reference

IMAGE = (640, 480)
BOX = (300.0, 200.0, 40.0, 30.0)  # 1200 px^2, wholly inside IMAGE
P = MonitorParams()  # zeta_e 0.0105, zeta_s 0.013, relative_drop 0.6, warm-up 30
AFTER_WARMUP = P.warmup_frames + 10


def _primed(level: float, frames: int = 1, params: MonitorParams = P) -> FailureMonitor:
    """A monitor whose reference is `level` (raw peak): `frames` reliable frames at that peak."""
    monitor = FailureMonitor(params)
    for k in range(frames):
        monitor.assess(level, BOX, IMAGE, AFTER_WARMUP + k)
    assert monitor.reference == pytest.approx(level)
    return monitor


def test_absolute_thresholds_alone_before_any_reference():
    monitor = FailureMonitor(P)
    assert monitor.reference is None
    assert monitor.judge(0.02) == (True, True)
    assert monitor.judge(0.012) == (True, False)  # between zeta_e and zeta_s: commit, do not train
    assert monitor.judge(P.confident_peak) == (False, False)  # strictly above zeta_e
    assert monitor.judge(P.reliable_peak) == (True, False)  # strictly above zeta_s
    assert monitor.judge(0.0) == (False, False)
    assert monitor.reference is None  # judge() changes nothing


def test_relative_rules_against_the_reference():
    monitor = _primed(0.05)
    # confident needs > 0.6 x 0.05 = 0.03 (far above zeta_e); reliable needs zeta_s alone
    assert monitor.judge(0.036) == (True, True)
    assert monitor.judge(0.029) == (False, True)  # far above zeta_e: the target was replaced
    assert monitor.judge(0.012) == (False, False)
    # the paper's rule alone (relative_drop 0): the reference plays no part
    paper = _primed(0.05, params=MonitorParams(relative_drop=0.0))
    assert paper.judge(0.011) == (True, False) and paper.judge(0.014) == (True, True)


def test_verdict_reports_the_reference_before_the_frame_and_lost_only_when_eligible():
    monitor = FailureMonitor(P)
    first = monitor.assess(0.05, BOX, IMAGE, AFTER_WARMUP)
    assert (first.confident, first.reliable, first.eligible, first.reference) == (True, True, True, None)
    assert not first.lost
    dropped = monitor.assess(0.02, BOX, IMAGE, AFTER_WARMUP + 1)  # < 0.6 x 0.05
    assert dropped.reference == pytest.approx(0.05)
    assert not dropped.confident and dropped.eligible and dropped.lost


def test_reference_rises_fast_and_falls_slowly():
    monitor = _primed(0.05)
    monitor.assess(0.06, BOX, IMAGE, AFTER_WARMUP + 1)
    assert monitor.reference == pytest.approx(0.05 + P.reference_rate * 0.01)  # 0.051
    up = monitor.reference
    monitor.assess(0.04, BOX, IMAGE, AFTER_WARMUP + 2)  # confident and reliable: the reference follows it down
    assert monitor.reference == pytest.approx(up + P.reference_fall_rate * (0.04 - up))
    assert up - monitor.reference < P.reference_rate * (up - 0.04)  # slower than it would rise
    assert updated_reference(None, 0.03, 0.1, 0.02) == 0.03
    assert updated_reference(0.05, 0.07, 0.1, 0.02) == pytest.approx(0.052)
    assert updated_reference(0.05, 0.03, 0.1, 0.02) == pytest.approx(0.0496)


def test_reference_follows_reliable_committed_frames_and_is_frozen_on_a_loss():
    monitor = _primed(0.05, frames=10)
    confident = monitor.assess(0.033, BOX, IMAGE, 60)  # confident (> 0.03) and reliable (> zeta_s)
    assert confident.confident and confident.reliable
    assert monitor.reference == pytest.approx(0.05 + P.reference_fall_rate * (0.033 - 0.05))
    before = monitor.reference
    assert monitor.assess(0.001, BOX, IMAGE, 90).lost  # a loss
    assert monitor.reference == pytest.approx(before)
    unreliable = FailureMonitor(dataclasses.replace(P, relative_drop=0.0))
    unreliable.assess(0.05, BOX, IMAGE, 1)
    assert not unreliable.assess(0.012, BOX, IMAGE, 2).reliable  # below zeta_s: committed, not learnt
    assert unreliable.reference == pytest.approx(0.05)


def test_a_reliable_frame_that_is_a_loss_does_not_move_the_reference():
    # A peak above zeta_s can be below relative_drop x the reference (reliable, not confident): on
    # an eligible frame it is a loss (not committed) and the reference must not learn it; in the
    # warm-up the same frame is committed and does.
    params = MonitorParams(relative_drop=0.9)
    lost = _primed(0.05, params=params)
    verdict = lost.assess(0.04, BOX, IMAGE, AFTER_WARMUP + 1)
    assert verdict.reliable and verdict.lost
    assert lost.reference == pytest.approx(0.05)
    warm = FailureMonitor(params)
    warm.assess(0.05, BOX, IMAGE, 1)
    early = warm.assess(0.04, BOX, IMAGE, 2)
    assert early.reliable and not early.eligible and not early.lost
    assert warm.reference == pytest.approx(0.05 + params.reference_fall_rate * (0.04 - 0.05))


def test_restart_forgets_the_reference():
    monitor = _primed(0.06, frames=5)
    assert monitor.assess(0.03, BOX, IMAGE, 50).lost  # < 0.6 x 0.06
    monitor.restart()
    assert monitor.reference is None
    again = monitor.assess(0.03, BOX, IMAGE, 51)  # the re-acquired target's level starts anew
    assert again.confident and again.reliable and again.reference is None
    assert monitor.reference == pytest.approx(0.03)


@pytest.mark.parametrize(("box", "frame", "why"), [
    (BOX, P.warmup_frames - 1, "warm-up: no loss before frame index warmup_frames"),
    ((300.0, 200.0, 4.0, 4.0), 40, "area 16 px^2 is not > min_area_px2 16"),
    ((300.0, 200.0, 200.0, 100.0), 40, "area 20000 px^2 is not < max_area_px2 20000"),
    ((620.0, 200.0, 40.0, 30.0), 40, "the box crosses the right border"),
    ((-1.0, 200.0, 40.0, 30.0), 40, "the box crosses the left border"),
])
def test_not_eligible_frames_are_committed_even_when_not_confident(box, frame, why):
    verdict = FailureMonitor(P).assess(0.0, box, IMAGE, frame)
    assert not verdict.confident and not verdict.eligible, why
    assert not verdict.lost, why


@pytest.mark.parametrize(("box", "frame"), [
    (BOX, P.warmup_frames),
    ((300.0, 200.0, 4.0, 4.1), 40),
    ((300.0, 200.0, 200.0, 99.9), 40),
    ((600.0, 450.0, 40.0, 30.0), 40),  # touching the bottom-right corner: still inside
])
def test_eligible_at_the_edges_of_each_rule(box, frame):
    assert FailureMonitor(P).assess(0.0, box, IMAGE, frame).lost


def test_inside_rules():
    crossing = (620.0, 200.0, 40.0, 30.0)  # centre at x = 640: outside too
    half_out = (610.0, 200.0, 40.0, 30.0)  # centre at x = 630: inside
    assert not box_is_inside(crossing, IMAGE, "full")
    assert not box_is_inside(half_out, IMAGE, "full")
    assert box_is_inside(half_out, IMAGE, "centre")
    assert not box_is_inside(crossing, IMAGE, "centre")
    assert box_is_inside((0.0, 0.0, 640.0, 480.0), IMAGE, "full")
    assert FailureMonitor(MonitorParams(inside_rule="centre")).assess(0.0, half_out, IMAGE, 40).lost
    assert not FailureMonitor(P).assess(0.0, half_out, IMAGE, 40).lost


def _decline(start: float, end: float, frames: int) -> list[float]:
    """Peaks falling linearly from start to end over `frames` frames (a target sliding under cover)."""
    return [start + (end - start) * k / (frames - 1) for k in range(frames)]


def _first_loss(monitor: FailureMonitor, peaks: list[float], first_frame: int = 31) -> int | None:
    """Index into `peaks` of the first frame the monitor declares a loss (None: never)."""
    for k, peak in enumerate(peaks):
        if monitor.assess(peak, BOX, IMAGE, first_frame + k).lost:
            return k
    return None


def test_gradual_decline_is_caught_while_still_above_the_absolute_thresholds():
    # The synthetic scene's canopy: peak 0.057 while clear, falling over 30 frames to 0.019 (above
    # zeta_e and zeta_s). A reference that followed the decline never fired.
    peaks = [0.057] * 30 + _decline(0.057, 0.019, 30)
    k = _first_loss(FailureMonitor(P), peaks)
    assert k is not None and 30 < k < 60
    assert peaks[k] > P.reliable_peak  # caught long before the absolute threshold
    assert peaks[k] < P.relative_drop * 0.057 + 1e-9
    # the defect the slow fall rate avoids: a running mean falling as fast as it rises is dragged
    # down by the decline and never fires
    dragged = dataclasses.replace(P, reference_fall_rate=P.reference_rate)
    assert _first_loss(FailureMonitor(dragged), peaks) is None


def test_slow_appearance_change_is_followed_without_a_loss():
    # the peak halves over 300 frames (pose / lighting): the slow fall rate still follows it
    peaks = [0.04] * 30 + _decline(0.04, 0.02, 300)
    monitor = FailureMonitor(P)
    verdicts = [monitor.assess(peak, BOX, IMAGE, 31 + k) for k, peak in enumerate(peaks)]
    assert not any(v.lost for v in verdicts)
    assert all(v.reliable for v in verdicts)
    assert monitor.reference < 0.03


def test_non_finite_peak_is_rejected():
    for peak in (float("nan"), float("inf"), float("-inf")):
        with pytest.raises(ValueError, match="finite"):
            FailureMonitor(P).assess(peak, BOX, IMAGE, 40)


@pytest.mark.parametrize(("override", "key"), [
    ({"confident_peak": 0.02, "reliable_peak": 0.01}, "monitor.confident_peak"),
    ({"confident_peak": 0.0}, "monitor.confident_peak"),
    ({"relative_drop": 1.0}, "monitor.relative_drop"),
    ({"reference_rate": 0.0}, "monitor.reference_rate"),
    ({"reference_fall_rate": 1.5}, "monitor.reference_fall_rate"),
    ({"warmup_frames": -1}, "monitor.warmup_frames"),
    ({"min_area_px2": 100.0, "max_area_px2": 100.0}, "monitor.min_area_px2"),
    ({"inside_rule": "half"}, "monitor.inside_rule"),
])
def test_invalid_values_are_named_by_key(override, key):
    params = dataclasses.replace(P, **override)
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        params.validate()
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        FailureMonitor(params)
    with pytest.raises(ValueError, match="redetect." + key.replace(".", r"\.")):
        params.validate("redetect.monitor")

