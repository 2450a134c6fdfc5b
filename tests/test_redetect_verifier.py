"""Track verification: the pure state machine, and the tracker giving up a track its long-term memory
does not recognise (a track on background) and finding the target again."""
from __future__ import annotations

import math

import numpy as np
import pytest

from jsar.config import JsarParams
from jsar.redetect.jsar_re import JsarReTracker, RedetectOptions
from jsar.redetect.verifier import TrackVerifier, VerifierParams
from tests.test_redetect_tracker import TARGET, _background, _target


def test_checks_are_due_every_n_committed_frames():
    verifier = TrackVerifier(VerifierParams(every_frames=3))
    due = [verifier.committed() for _ in range(3)]
    assert due == [False, False, True]
    verifier.check(0.05)
    assert [verifier.committed() for _ in range(3)] == [False, False, True]
    assert not any(TrackVerifier(VerifierParams(every_frames=0)).committed() for _ in range(50))


def test_consecutive_doubts_fail_the_track_and_a_good_check_clears_them():
    verifier = TrackVerifier(VerifierParams(min_fraction=0.35, failures=3, band=0.7))
    assert verifier.check(0.04) is False and verifier.reference == 0.04
    # 0.013 < 0.35 * 0.04 = 0.014: a doubt; the memory must not learn meanwhile
    assert verifier.check(0.013) is False and not verifier.trusted
    assert verifier.check(0.013) is False
    assert verifier.check(0.02) is False and verifier.trusted  # 0.5 x reference: no doubt, no update
    assert verifier.reference == 0.04
    assert [verifier.check(0.01) for _ in range(3)] == [False, False, True]
    assert verifier.trusted  # reset after failing: the caller re-detects


def test_reference_follows_in_band_scores_only():
    verifier = TrackVerifier(VerifierParams(rise_rate=0.5, fall_rate=0.25, band=0.7))
    verifier.check(0.04)
    verifier.check(0.06)
    assert verifier.reference == pytest.approx(0.05)
    verifier.check(0.04)  # 0.8 x reference: in band, falls slowly
    assert verifier.reference == pytest.approx(0.0475)
    verifier.check(0.02)  # out of band: a wrong track cannot drag the reference down
    assert verifier.reference == pytest.approx(0.0475)


def test_parameters_are_validated():
    with pytest.raises(ValueError, match="min_fraction"):
        VerifierParams(min_fraction=0.8, band=0.7)
    with pytest.raises(ValueError, match="failures"):
        VerifierParams(failures=-1)
    with pytest.raises(ValueError, match="finite"):
        TrackVerifier().check(math.nan)


def _run_track_forced_onto_background(background_xy: tuple[int, int], verify: bool = True, frames: int = 160,
                                      verifier: VerifierParams = VerifierParams()):
    """The target drifts right (0.5 px per frame); at frame 40 the core is re-initialised on empty
    background at background_xy (what a slow slide onto an occluder ends in; no probation, the decision
    filter keeps its memory). Returns frame -> (state, box), frame -> whether the decision filter changed
    on that frame, and the target's top-left corner per frame."""
    background = _background()

    def target_xy(index: int) -> tuple[int, int]:
        return 100 + index // 2, 100

    def frame(index: int) -> np.ndarray:
        image = background.copy()
        x, y = target_xy(index)
        image[y:y + TARGET, x:x + TARGET] = _target()
        return image

    options = RedetectOptions(verifier=verifier if verify else VerifierParams(every_frames=0))
    tracker = JsarReTracker(JsarParams.jsar_re(), options)
    tracker.init(frame(0), (100.0, 100.0, TARGET, TARGET))
    results, learned = {}, {}
    for index in range(1, frames + 1):
        assert tracker.decision is not None
        before = tracker.decision.filter_f.copy()
        if index == 40:
            tracker.core.reinitialise(frame(index), (*map(float, background_xy), TARGET, TARGET))
            tracker.monitor.reinitialised()  # a fresh peak history, as after any re-initialisation
        result = tracker.update(frame(index))
        results[index] = (result.state, result.box)
        learned[index] = not np.array_equal(before, tracker.decision.filter_f)
    return results, learned, target_xy


def _centre(box: tuple[float, ...]) -> tuple[float, float]:
    return box[0] + box[2] / 2, box[1] + box[3] / 2


def test_a_doubtful_track_switches_to_the_target_nearby():
    background_xy = (140, 150)  # about 2 target sides from the target
    # Without verification the translation filter follows the background patch for good, confidently.
    plain, _, _ = _run_track_forced_onto_background(background_xy, verify=False, frames=120)
    assert all(plain[i][0] == "tracking" for i in range(40, 121))
    assert math.dist(_centre(plain[120][1]), (152.0, 162.0)) < 4
    # With it: a check (every 10 committed frames) doubts the track, the challenge finds the target.
    results, learned, target_xy = _run_track_forced_onto_background(background_xy, frames=120)
    switched = [i for i in range(40, 121) if results[i][0] != "tracking"]
    assert switched and switched[0] <= 40 + 10 and results[switched[0]][0] == "recovered", switched[:3]
    # the long-term memory learned nothing from the background track
    assert not any(learned[i] for i in range(40, switched[0] + 1))

    def on_target(i: int) -> bool:
        x, y = target_xy(i)
        return math.dist(_centre(results[i][1]), (x + TARGET / 2, y + TARGET / 2)) < 6

    assert all(on_target(i) for i in range(switched[0], 121))


def test_a_track_doubted_for_long_is_given_up_and_the_target_found_again():
    # Too far for a challenge (the target is outside the proposal square around the track): with
    # `failures` set, that many doubtful checks in a row declare the track lost (off by default).
    failures = 5
    results, learned, target_xy = _run_track_forced_onto_background((20, 190), frames=40 + 10 * failures + 20,
                                                                    verifier=VerifierParams(failures=failures))
    left = [i for i in range(40, len(results) + 1) if results[i][0] != "tracking"]
    assert left and results[left[0]][0] == "lost" and left[0] <= 40 + 10 * failures, left[:3]
    assert not any(learned[i] for i in range(40, left[0] + 1))
    assert math.dist(_centre(results[left[0]][1]), (32.0, 202.0)) < 4  # lost reports the given-up box
    # by default the track is kept (and challenged at every doubtful check)
    kept, _, _ = _run_track_forced_onto_background((20, 190), frames=40 + 10 * failures + 20)
    assert all(kept[i][0] == "tracking" for i in range(40, len(kept) + 1))
