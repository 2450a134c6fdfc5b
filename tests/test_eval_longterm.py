"""Long-term protocol: event injection on a synthetic OTB sequence, and the long-term metrics."""
import numpy as np
import pytest

from jsar.eval import dataset, longterm
from jsar.eval.synthetic import synthetic_clip, write_otb_sequence

CONFIG = longterm.InjectionConfig(first_start=5, gap_after=4)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    frames, boxes = synthetic_clip(n_frames=40, size=(120, 160), object_size=(20, 16), seed=3)
    return dataset.load_sequence(write_otb_sequence(tmp_path_factory.mktemp("lt") / "syn", frames, boxes))


def red_pixels(frame: np.ndarray) -> int:
    """Object pixels: saturated red; the synthetic background is grey."""
    b, g, r = (frame[..., i].astype(int) for i in range(3))
    return int(np.count_nonzero((r > 180) & (r - g > 100) & (r - b > 100)))


@pytest.mark.parametrize("kind", longterm.INJECTED_KINDS)
def test_injected_events_hide_the_target_and_mark_it_absent(sequence, kind):
    events = longterm.inject_events(sequence, kind, (3, 6), seed=7, config=CONFIG)
    assert [e.length for e in sorted(events.events, key=lambda e: e.length)] == [3, 6]
    inside = np.zeros(len(sequence), bool)
    for span in events.events:
        assert span.start >= CONFIG.first_start
        inside[span.start:span.stop] = True
    assert np.all(np.isnan(events.groundtruth[inside]))
    np.testing.assert_array_equal(events.groundtruth[~inside], sequence.groundtruth[~inside])
    for index in range(len(sequence)):
        original = sequence.read_frame(index)
        frame = events.frame(index)
        assert frame.shape == original.shape
        if inside[index]:
            assert red_pixels(original) > 200
            assert red_pixels(frame) == 0, f"target visible in event frame {index}"
        else:
            np.testing.assert_array_equal(frame, original)


def test_same_seed_same_events_and_no_overlap(sequence):
    a = longterm.inject_events(sequence, "occlusion", (3, 6, 9), seed=11, config=CONFIG)
    b = longterm.inject_events(sequence, "occlusion", (3, 6, 9), seed=11, config=CONFIG)
    assert a.events == b.events and a.fills == b.fills
    spans = sorted((e.start, e.stop) for e in a.events)
    for (s0, e0), (s1, _) in zip(spans, spans[1:]):
        assert s1 >= e0 + CONFIG.gap_after
    starts = {longterm.inject_events(sequence, "occlusion", (3, 6, 9), seed=s, config=CONFIG).events
              for s in range(6)}
    assert len(starts) > 1  # the seed changes the placement


def test_lengths_that_do_not_fit_are_reported_not_hidden():
    spans, dropped = longterm.place_events(60, (5, 15, 40), np.random.default_rng(0), 30, 15)
    assert dropped == [40, 15] and [length for _, length in spans] == [5]
    with pytest.raises(ValueError, match="unknown event kind"):
        longterm.inject_events(None, "fog")  # type: ignore[arg-type]


def test_longterm_scores_hand_case():
    gt = np.array([[0, 0, 10, 10]] * 12, float)
    gt[3:6] = np.nan  # target absent on frames 3, 4, 5; reappears at 6
    pred = gt.copy()
    pred[3:8] = [60, 60, 10, 10]  # stays away until frame 8
    pred[8:] = [0, 0, 10, 10]
    states = ["tracking"] * 12
    states[4] = "recovered"  # a re-init while absent: false
    criteria = longterm.LongTermCriteria(window=5)
    result = longterm.longterm_scores(pred, states, gt, criteria)
    assert result["n_events"] == 1 and result["n_reacquired"] == 1
    assert result["frames_to_recover"] == [2]  # frame 8 - frame 6
    assert result["events"][0]["on_target_before"]  # frame 2 on target
    assert result["absent_frames"] == 3
    # frame 3: jump from (5,5) to (65,65) while absent; frame 4: "recovered" while absent.
    assert result["false_reinit_absent"] == 2
    assert result["false_reinit_wrong_object"] == 0
    late = longterm.longterm_scores(pred, states, gt, longterm.LongTermCriteria(window=2))
    assert late["n_reacquired"] == 0
    wrong = list(states)
    wrong[7] = "recovered"  # re-initialised onto something with IoU 0 while the target is visible
    assert longterm.longterm_scores(pred, wrong, gt, criteria)["false_reinit_wrong_object"] == 1
    drifted = pred.copy()
    drifted[2] = [60, 60, 10, 10]  # already off the target on the frame before the event
    off = longterm.longterm_scores(drifted, states, gt, criteria)
    assert not off["events"][0]["on_target_before"] and off["n_reacquired"] == 1
    summary = longterm.summarise_longterm([result, late])
    assert summary["reacquisition_rate"] == 0.5
    assert summary["n_events_on_target_before"] == 2 and summary["reacquisition_rate_on_target_before"] == 0.5
    began_off = longterm.summarise_longterm([off])
    assert began_off["n_events_on_target_before"] == 0 and began_off["reacquisition_rate_on_target_before"] is None
    assert summary["false_reinit_rate"] == pytest.approx(4 / 6)


def with_absent_run(sequence, start, stop):
    """`sequence` with its ground truth NaN on frames [start, stop) (an annotated real absence)."""
    gt = np.array(sequence.groundtruth)
    gt[start:stop] = np.nan
    return dataset.Sequence(sequence.name, sequence.frame_paths, gt)


def test_real_events_are_the_ground_truths_own_absent_runs_on_unchanged_frames(sequence):
    real = longterm.inject_events(with_absent_run(sequence, 10, 14), "real", config=CONFIG)
    assert [(e.kind, e.start, e.length) for e in real.events] == [("real", 10, 4)]
    assert real.scored_spans == [(10, 14)]
    np.testing.assert_array_equal(real.frame(12), sequence.read_frame(12))
    # a run that lasts to the end never reappears: not an event
    assert longterm.inject_events(with_absent_run(sequence, 35, 40), "real", config=CONFIG).events == ()
    assert longterm.inject_events(sequence, "real", config=CONFIG).events == ()


def test_injected_events_keep_clear_of_real_absent_runs(sequence):
    blocked = with_absent_run(sequence, 12, 16)
    for seed in range(8):
        events = longterm.inject_events(blocked, "occlusion", (3, 6), seed=seed, config=CONFIG)
        for span in events.events:
            assert span.stop + CONFIG.gap_after <= 12 or span.start >= 16, (seed, span)
    # no room left around a long absent run: the longest length is dropped and reported, not hidden
    crowded = longterm.inject_events(with_absent_run(sequence, 8, 30), "occlusion", (3, 20), seed=1, config=CONFIG)
    assert [e.length for e in crowded.events] == [3] and crowded.dropped_lengths == (20,)
    # no absent frame: the first draw is kept, as before real runs were avoided
    plain = longterm.inject_events(sequence, "occlusion", (3, 6), seed=5, config=CONFIG)
    spans, _ = longterm.place_events(len(sequence), (3, 6), longterm.event_rng(5, sequence.name),
                                     CONFIG.first_start, CONFIG.gap_after)
    assert sorted((e.start, e.length) for e in plain.events) == sorted(spans)


def test_scoring_on_given_spans_counts_only_those_events_and_absent_frames():
    gt = np.array([[0, 0, 10, 10]] * 30, float)
    gt[3:6] = np.nan  # a real absence, scored in another run
    gt[12:15] = np.nan  # this run's event
    pred = gt.copy()
    pred[np.isnan(pred[:, 0])] = [0, 0, 10, 10]
    states = ["tracking"] * 30
    states[12:15] = ["lost"] * 3
    states[4] = "recovered"  # inside the real absence: not this run's
    result = longterm.longterm_scores(pred, states, gt, longterm.LongTermCriteria(window=5), [(12, 15)])
    assert result["n_events"] == 1 and result["events"][0]["start"] == 12
    assert result["absent_frames"] == 3 and result["false_reinit_absent"] == 0
    assert result["absent_reported_lost"] == 3
    everything = longterm.longterm_scores(pred, states, gt, longterm.LongTermCriteria(window=5))
    assert everything["n_events"] == 2 and everything["false_reinit_absent"] == 1
    with pytest.raises(ValueError, match="visible"):
        longterm.longterm_scores(pred, states, gt, None, [(10, 15)])
