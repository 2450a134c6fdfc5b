"""Failure-monitor state machine: threshold crossings, omega growth, eta_d decay, reset, gating."""
from __future__ import annotations

import pytest

from jsar.redetect.monitor import FailureMonitor, MonitorParams, box_is_inside

IMAGE = (640, 480)
BOX = (300.0, 200.0, 40.0, 30.0)  # 1200 px^2, fully inside
P = MonitorParams(accept_holdoff=0)  # zeta_e 0.01, zeta_s 0.013, eta_d 0.02, omega 5; hold-off tested apart


def test_threshold_crossings_decide_commit_reliable_and_redetect():
    monitor = FailureMonitor(MonitorParams(relative_drop=0.0, accept_holdoff=0))  # the paper's absolute rule alone
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
    monitor = FailureMonitor(MonitorParams(omega_max=6.0, accept_holdoff=0))
    for frame in range(10):
        verdict = monitor.assess(0.0, BOX, IMAGE, 40 + frame)
        monitor.redetection_result(False)
    assert verdict.omega == pytest.approx(6.0)
    assert verdict.eta_d == pytest.approx(0.02 / 1.005 ** 9)
    with pytest.raises(ValueError, match="omega_max"):
        MonitorParams(omega_max=4.0)


def _decline(start: float, end: float, frames: int) -> list[float]:
    """Peaks falling linearly from start to end over `frames` frames (a target sliding under cover)."""
    return [start + (end - start) * k / (frames - 1) for k in range(frames)]


def _first_redetect(monitor: FailureMonitor, peaks: list[float], first_frame: int = 31) -> int | None:
    """Index into `peaks` of the first frame the monitor asks for a re-detection (None: never)."""
    for k, peak in enumerate(peaks):
        if monitor.assess(peak, BOX, IMAGE, first_frame + k).redetect:
            return k
    return None


def test_gradual_decline_of_the_peak_triggers_redetection_while_still_above_zeta_e():
    # The synthetic scene's canopy: peak 0.057 while clear, falling over 30 frames to 0.019 (above
    # zeta_e = 0.01 and zeta_s = 0.013). A reference that followed the decline never fired.
    steady, falling = [0.057] * 30, _decline(0.057, 0.019, 30)
    k = _first_redetect(FailureMonitor(P), steady + falling)
    assert k is not None and 30 < k < 60
    assert (steady + falling)[k] > P.reliable_peak  # caught long before the absolute threshold
    assert (steady + falling)[k] < P.relative_drop * 0.057 + 1e-9
    # the defect it fixes: a running mean updated on every frame above zeta_s (fall rate = rise rate,
    # no reliable band) is dragged down by the decline and never fires
    dragged = MonitorParams(reference_fall_rate=P.reference_rate, reliable_fraction=0.0)
    assert _first_redetect(FailureMonitor(dragged), steady + falling) is None
    # either remedy alone catches it: the slow fall rate, or freezing the reference below the band
    for remedy in (MonitorParams(reliable_fraction=0.0), MonitorParams(reference_fall_rate=P.reference_rate)):
        assert _first_redetect(FailureMonitor(remedy), steady + falling) is not None


def test_decision_filter_sample_unreliable_once_peak_leaves_the_reference_band():
    monitor = FailureMonitor(P)
    for k in range(10):
        monitor.assess(0.05, BOX, IMAGE, 31 + k)
    inside = monitor.assess(0.036, BOX, IMAGE, 41)  # > 0.7 * 0.05: still the target's appearance
    assert not inside.redetect and inside.reliable
    partial = monitor.assess(0.033, BOX, IMAGE, 42)  # confident (> 0.6 * ref) but partly covered
    assert not partial.redetect and not partial.reliable
    reference = partial.reference
    for k in range(20):  # the reference is frozen while the peak stays below the band
        assert monitor.assess(0.032, BOX, IMAGE, 43 + k).reference == reference


def test_slow_appearance_change_is_followed_without_redetection():
    # peak halves over 300 frames (pose / lighting change): the slow fall rate still follows it
    peaks = [0.04] * 30 + _decline(0.04, 0.02, 300)
    monitor = FailureMonitor(P)
    verdicts = [monitor.assess(peak, BOX, IMAGE, 31 + k) for k, peak in enumerate(peaks)]
    assert not any(v.redetect for v in verdicts)
    assert all(v.reliable for v in verdicts)


def test_acceptance_threshold_has_a_relative_floor_that_decays_with_eta_d():
    monitor = FailureMonitor(P)  # accept_fraction 0.5
    for k in range(5):
        monitor.assess(0.06, BOX, IMAGE, 31 + k)
    first = monitor.assess(0.005, BOX, IMAGE, 36)
    assert first.redetect and first.eta_d == pytest.approx(0.5 * 0.06)  # above the absolute 0.02
    monitor.redetection_result(False)
    second = monitor.assess(0.005, BOX, IMAGE, 37)
    assert second.eta_d == pytest.approx(0.03 / 1.005)
    monitor.redetection_result(False)
    low = FailureMonitor(P)
    for k in range(5):
        low.assess(0.03, BOX, IMAGE, 31 + k)
    assert low.assess(0.005, BOX, IMAGE, 36).eta_d == pytest.approx(P.accept_peak)  # 0.5 * 0.03 < 0.02
    with pytest.raises(ValueError, match="accept_fraction"):
        MonitorParams(accept_fraction=1.0)
    with pytest.raises(ValueError, match="reference_fall_rate"):
        MonitorParams(reference_fall_rate=0.0)


def test_no_acceptance_during_the_holdoff_at_the_start_of_a_loss():
    params = MonitorParams()  # accept_holdoff 5
    monitor = FailureMonitor(params)
    etas = []
    for k in range(8):
        verdict = monitor.assess(0.001, BOX, IMAGE, 40 + k)
        etas.append(verdict.eta_d)
        monitor.redetection_result(False)
        assert verdict.omega == pytest.approx(5.0 * 1.05 ** k)  # the square still grows meanwhile
    assert etas[:5] == [float("inf")] * 5
    assert etas[5] == pytest.approx(0.02 / 1.005 ** 5)
    monitor.assess(0.05, BOX, IMAGE, 48)  # confident again: a new loss starts a new hold-off
    assert monitor.assess(0.001, BOX, IMAGE, 49).eta_d == float("inf")
    with pytest.raises(ValueError, match="accept_holdoff"):
        MonitorParams(accept_holdoff=-1)


def test_acceptance_threshold_has_a_ceiling_at_a_fraction_of_a_weak_targets_level():
    params = MonitorParams(accept_holdoff=0, accept_ceiling_fraction=0.8)
    monitor = FailureMonitor(params)
    for k in range(5):
        monitor.assess(0.018, BOX, IMAGE, 31 + k)  # a weak target: its level is below the absolute 0.02
    first = monitor.assess(0.005, BOX, IMAGE, 36)
    assert first.eta_d == pytest.approx(0.8 * 0.018)
    monitor.redetection_result(False)
    for k in range(200):  # the decay goes on below the ceiling
        verdict = monitor.assess(0.005, BOX, IMAGE, 37 + k)
        monitor.redetection_result(False)
    assert verdict.eta_d == pytest.approx(0.02 / 1.005 ** 200)
    # A strong target: the relative floor (0.5 x 0.06) is below the ceiling (0.8 x 0.06) and wins.
    strong = FailureMonitor(params)
    for k in range(5):
        strong.assess(0.06, BOX, IMAGE, 31 + k)
    assert strong.assess(0.005, BOX, IMAGE, 36).eta_d == pytest.approx(0.5 * 0.06)
    # No ceiling without a reference, nor with the fraction 0 (the paper's absolute eta_d).
    assert FailureMonitor(params).assess(0.001, BOX, IMAGE, 36).eta_d == pytest.approx(0.02)
    assert FailureMonitor(P).assess(0.001, BOX, IMAGE, 36).eta_d == pytest.approx(0.02)
    with pytest.raises(ValueError, match="accept_ceiling_fraction"):
        MonitorParams(accept_ceiling_fraction=0.4)  # not above accept_fraction
    with pytest.raises(ValueError, match="accept_ceiling_fraction"):
        MonitorParams(accept_ceiling_fraction=1.5)
