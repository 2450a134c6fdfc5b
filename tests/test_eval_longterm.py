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


@pytest.mark.parametrize("kind", longterm.EVENT_KINDS)
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
    assert result["absent_frames"] == 3
    # frame 3: jump from (5,5) to (65,65) while absent; frame 4: "recovered" while absent.
    assert result["false_reinit_absent"] == 2
    assert result["false_reinit_wrong_object"] == 0
    late = longterm.longterm_scores(pred, states, gt, longterm.LongTermCriteria(window=2))
    assert late["n_reacquired"] == 0
    wrong = list(states)
    wrong[7] = "recovered"  # re-initialised onto something with IoU 0 while the target is visible
    assert longterm.longterm_scores(pred, wrong, gt, criteria)["false_reinit_wrong_object"] == 1
    summary = longterm.summarise_longterm([result, late])
    assert summary["reacquisition_rate"] == 0.5
    assert summary["false_reinit_rate"] == pytest.approx(4 / 6)
