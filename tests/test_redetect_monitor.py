"""Failure-monitor state machine: threshold crossings, omega growth, eta_d decay, reset, gating."""
from __future__ import annotations

import pytest

from jsar.redetect.monitor import FailureMonitor, MonitorParams, box_is_inside

IMAGE = (640, 480)
BOX = (300.0, 200.0, 40.0, 30.0)  # 1200 px^2, fully inside
P = MonitorParams()  # zeta_e 0.01, zeta_s 0.013, eta_d 0.02, omega 5


def test_threshold_crossings_decide_commit_reliable_and_redetect():
    monitor = FailureMonitor(MonitorParams(relative_drop=0.0))  # the paper's absolute rule alone
    high = monitor.assess(0.02, BOX, IMAGE, 40)
    assert not high.redetect and high.reliable
    middle = monitor.assess(0.012, BOX, IMAGE, 41)  # confident but not reliable
    assert not middle.redetect and not middle.reliable
    at_threshold = monitor.assess(P.enable_peak, BOX, IMAGE, 42)  # not strictly above zeta_e
    assert at_threshold.redetect and not at_threshold.reliable
    assert (at_threshold.omega, at_threshold.eta_d) == (P.omega, P.accept_peak)


def test_relative_drop_against_the_running_reference_of_reliable_peaks():
    monitor = FailureMonitor(P)  # relative_drop 0.6, reference_rate 0.1
    first = monitor.assess(0.02, BOX, IMAGE, 31)
    assert first.reference is None and first.reliable
    unreliable = monitor.assess(0.0125, BOX, IMAGE, 32)  # > zeta_e and > 0.6 * 0.02, < zeta_s
    assert not unreliable.redetect and not unreliable.reliable and unreliable.reference == pytest.approx(0.02)
    assert monitor.assess(0.03, BOX, IMAGE, 33).reference == pytest.approx(0.02)  # unreliable: no update
    # 0.0125 is above zeta_e but now below 0.6 * 0.021: the target was replaced by something else
    dropped = monitor.assess(0.0125, BOX, IMAGE, 34)
    assert dropped.redetect and dropped.reference == pytest.approx(0.021)
    monitor.redetection_result(accepted=True)
    # after a re-initialisation the reference restarts from the new filter's peaks
    assert monitor.assess(0.015, BOX, IMAGE, 35).reference is None


def test_omega_grows_and_eta_decays_per_failed_frame_then_reset_after_recovery():
    monitor = FailureMonitor(P)
    for failed in range(5):
        verdict = monitor.assess(0.001, BOX, IMAGE, 50 + failed)
        assert verdict.redetect and verdict.failed_frames == failed
        assert verdict.omega == pytest.approx(5.0 * 1.05 ** failed)
        assert verdict.eta_d == pytest.approx(0.02 / 1.005 ** failed)
        monitor.redetection_result(accepted=False)
    assert monitor.searching
    verdict = monitor.assess(0.001, BOX, IMAGE, 55)
    monitor.redetection_result(accepted=True)  # recovered by a proposal
    assert not monitor.searching
    again = monitor.assess(0.001, BOX, IMAGE, 56)
    assert (again.omega, again.eta_d, again.failed_frames) == (P.omega, P.accept_peak, 0)


def test_confident_frame_also_resets_the_search():
    monitor = FailureMonitor(P)
    for frame in range(3):
        monitor.assess(0.0, BOX, IMAGE, 60 + frame)
        monitor.redetection_result(False)
    assert monitor.assess(0.05, BOX, IMAGE, 63).redetect is False  # target back under the filter
    assert monitor.assess(0.0, BOX, IMAGE, 64).omega == P.omega


@pytest.mark.parametrize(("box", "frame", "why"), [
    (BOX, 29, "warm-up: not before frame 30 (0-based index 30 = 31st frame)"),
    ((300.0, 200.0, 8.0, 12.0), 40, "area 96 <= 100 px^2"),
    ((300.0, 200.0, 200.0, 100.0), 40, "area 20000 px^2 is not < 20000"),
    ((620.0, 200.0, 40.0, 30.0), 40, "box crosses the right border"),
])
def test_no_redetection_when_not_eligible_then_frame_is_committed(box, frame, why):
    verdict = FailureMonitor(P).assess(0.0, box, IMAGE, frame)
    assert not verdict.redetect, why
    assert not verdict.reliable


def test_inside_rules():
    crossing = (620.0, 200.0, 40.0, 30.0)  # centre at x = 640 -> outside too
    assert not box_is_inside(crossing, IMAGE, "full")
    assert box_is_inside((610.0, 200.0, 40.0, 30.0), IMAGE, "centre")
    assert not box_is_inside(crossing, IMAGE, "centre")
    centre_monitor = FailureMonitor(MonitorParams(inside_rule="centre"))
    assert centre_monitor.assess(0.0, (610.0, 200.0, 40.0, 30.0), IMAGE, 40).redetect


def test_protocol_misuse_and_bad_values_are_named():
    monitor = FailureMonitor(P)
    with pytest.raises(RuntimeError, match="without a re-detection"):
        monitor.redetection_result(True)
    monitor.assess(0.0, BOX, IMAGE, 40)
    with pytest.raises(RuntimeError, match="before redetection_result"):
        monitor.assess(0.0, BOX, IMAGE, 41)
    with pytest.raises(ValueError, match="finite"):
        FailureMonitor(P).assess(float("nan"), BOX, IMAGE, 41)
    with pytest.raises(ValueError, match="enable_peak <= reliable_peak"):
        MonitorParams(enable_peak=0.02, reliable_peak=0.01)
    with pytest.raises(ValueError, match="inside_rule"):
        MonitorParams(inside_rule="half")  # type: ignore[arg-type]


def test_omega_growth_stops_at_omega_max_while_eta_keeps_decaying():
    monitor = FailureMonitor(MonitorParams(omega_max=6.0))
    for frame in range(10):
        verdict = monitor.assess(0.0, BOX, IMAGE, 40 + frame)
        monitor.redetection_result(False)
    assert verdict.omega == pytest.approx(6.0)
    assert verdict.eta_d == pytest.approx(0.02 / 1.005 ** 9)
    with pytest.raises(ValueError, match="omega_max"):
        MonitorParams(omega_max=4.0)
