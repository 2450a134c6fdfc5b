"""The verifier's memories and verdicts (jsar.redetect.appearance), on hand-made unit embeddings."""
from __future__ import annotations

import concurrent.futures
import threading

import numpy as np
import pytest

from jsar.redetect.appearance import AppearanceMemory, DeferredEmbeddings, Verdict, map_peaks, max_cosine, ring_boxes
from jsar.redetect.params import RedetectParams, VerifyParams


def unit(*values: float) -> np.ndarray:
    row = np.asarray(values, np.float32)
    return row / np.linalg.norm(row)


def test_max_cosine_takes_the_closest_memory_row_and_minus_one_for_an_empty_memory():
    memory = np.vstack([unit(1, 0, 0), unit(0, 1, 0)])
    rows = np.vstack([unit(1, 1, 0), unit(0, 0, 1)])
    assert max_cosine(rows, memory) == pytest.approx([np.sqrt(0.5), 0.0], abs=1e-6)
    assert max_cosine(rows, np.empty((0, 3), np.float32)).tolist() == [-1.0, -1.0]


def test_the_selection_itself_is_the_target_and_an_orthogonal_window_another_object():
    memory = AppearanceMemory(VerifyParams(reject_nearer_other=False), unit(1, 0, 0))
    target, other = memory.judge(np.vstack([unit(1, 0.1, 0), unit(0, 0, 1)]))
    assert target.verdict is Verdict.TARGET and target.other == -1.0
    assert other.verdict is Verdict.OTHER


def test_a_look_alike_as_close_as_the_target_leaves_a_candidate_unsure_and_a_far_one_other():
    params = VerifyParams(min_similarity=0.7, margin=0.05, reject_similarity=0.3)
    memory = AppearanceMemory(params, unit(1, 0, 0))
    memory.learn_others(unit(0, 1, 0)[None])
    between = unit(1, 1, 0)  # cos 0.707 to both: close enough, but no margin
    assert memory.judge(between[None])[0].verdict is Verdict.UNSURE
    nearer = unit(1, 0.8, 0)  # cos 0.78 to the target, 0.62 to the look-alike
    assert memory.judge(nearer[None])[0].verdict is Verdict.TARGET
    far = unit(0.2, 1, 0)  # cos 0.2 to the target: under reject_similarity
    assert memory.judge(far[None])[0].verdict is Verdict.OTHER


def test_with_reject_nearer_other_a_look_unlike_every_memory_is_unsure_not_other():
    """A target back from an occlusion turned looks like neither memory: it is refused only when a look-alike
    is at least as near as the target memory."""
    memory = AppearanceMemory(VerifyParams(reject_similarity=0.5), unit(1, 0, 0))
    turned = unit(0.3, 0, 1)  # cos 0.29 to the target, and no look-alike learnt yet
    assert memory.judge(turned[None])[0].verdict is Verdict.UNSURE
    memory.learn_others(unit(0, 0.2, 1)[None])  # a look-alike nearer to it (cos 0.92) than the target is
    assert memory.judge(turned[None])[0].verdict is Verdict.OTHER
    strict = AppearanceMemory(VerifyParams(reject_similarity=0.5, reject_nearer_other=False), unit(1, 0, 0))
    assert strict.judge(turned[None])[0].verdict is Verdict.OTHER


def test_a_candidate_close_enough_but_without_the_margin_is_unsure():
    params = VerifyParams(min_similarity=0.7, margin=0.3, reject_similarity=0.3)
    memory = AppearanceMemory(params, unit(1, 0, 0))
    memory.learn_others(unit(0.3, 1, 0)[None])  # cos 0.29 to the target: a look-alike it keeps
    look = memory.judge(unit(1, 0.5, 0)[None])[0]
    assert look.target == pytest.approx(0.894, abs=1e-3) and look.other == pytest.approx(0.685, abs=1e-3)
    assert look.verdict is Verdict.UNSURE  # close enough, but only 0.21 above the look-alike
    assert AppearanceMemory(VerifyParams(min_similarity=0.7, margin=0.2), unit(1, 0, 0)).judge(
        unit(1, 0.5, 0)[None])[0].verdict is Verdict.TARGET  # with no look-alike learnt


def test_look_alikes_close_to_the_target_are_not_learnt_and_the_oldest_go_first():
    params = VerifyParams(min_similarity=0.75, other_slots=2)
    memory = AppearanceMemory(params, unit(1, 0, 0))
    memory.learn_others(np.vstack([unit(1, 0.2, 0), unit(0, 1, 0), unit(0, 0, 1), unit(0, 1, 1)]))
    others = memory.other_rows()
    assert len(others) == 2  # the first was the target's own look; of three others the oldest went
    assert np.allclose(others, np.vstack([unit(0, 0, 1), unit(0, 1, 1)]))


def test_the_target_memory_keeps_the_selection_and_the_latest_frames():
    memory = AppearanceMemory(VerifyParams(target_slots=3), unit(1, 0, 0))
    for row in (unit(1, 0.2, 0), unit(1, 0.3, 0), unit(1, 0, 0.4)):
        memory.learn_target(row)
    assert np.allclose(memory.target_rows(), np.vstack([unit(1, 0, 0), unit(1, 0.3, 0), unit(1, 0, 0.4)]))


def test_ring_boxes_surround_the_box_at_its_size_and_drop_centres_outside_the_frame():
    boxes = ring_boxes((10.0, 20.0, 20.0, 20.0), 2.0, 4, (200, 200))  # centre (20, 30), 40 px away
    centres = boxes[:, :2] + boxes[:, 2:] / 2
    assert np.allclose(centres, [[60.0, 30.0], [20.0, 70.0]])  # left (-20, 30) and up (20, -10) lie outside
    assert np.all(boxes[:, 2:] == 20.0)


@pytest.mark.parametrize("key, value", [("margin", -0.1), ("bar_fraction", 0.0), ("target_slots", 0),
                                        ("ring_sides", 0.0), ("min_similarity", 1.5),
                                        ("anchor_similarity", -1.5)])
def test_an_invalid_verifier_setting_is_named(key, value):
    with pytest.raises(ValueError, match=rf"redetect\.verify\.{key}"):
        RedetectParams.from_mapping({"verify": {key: value}})


def test_map_peaks_keeps_the_best_maxima_a_spacing_apart_above_the_minimum():
    score = np.zeros((10, 10), np.float32)
    score[2, 2], score[2, 3], score[7, 7], score[5, 5], score[9, 0] = 1.0, 0.9, 0.8, 0.3, 0.7
    assert map_peaks(score, 3, 0.5, 2.0) == [(2, 2, 1.0), (7, 7, pytest.approx(0.8)), (9, 0, pytest.approx(0.7))]
    assert map_peaks(score, 1, 0.5, 2.0) == [(2, 2, 1.0)]
    assert map_peaks(score, 5, 0.75, 0.5) == [(2, 2, 1.0), (2, 3, pytest.approx(0.9)), (7, 7, pytest.approx(0.8))]


def test_the_target_memory_does_not_learn_a_look_it_would_call_another_object():
    memory = AppearanceMemory(VerifyParams(reject_similarity=0.5), unit(1, 0, 0))
    assert memory.learn_target(unit(1, 0.5, 0))  # cos 0.89: the target, changed a little
    memory.learn_others(unit(0.1, 1, 0)[None])  # a look-alike seen beside it
    assert not memory.learn_target(unit(0, 1, 0))  # cos 0.45 to the target, 0.99 to the look-alike: a slide onto it
    assert len(memory.target_rows()) == 2


@pytest.mark.parametrize("anchor, kept_up_to_degrees", [(0.55, 50), (-1.0, 80)])
def test_the_target_memory_does_not_follow_a_slow_slide_away_from_the_selection(anchor, kept_up_to_degrees):
    """Looks 10 degrees apart, each near the last one learnt (cos 0.98) but ever further from the selection:
    bounded by the selection (anchor_similarity), the memory stops where the cosine to it falls under the
    bound (cos 60 degrees = 0.5); unbounded (-1), it follows the slide to the end."""
    memory = AppearanceMemory(VerifyParams(anchor_similarity=anchor, target_slots=3), unit(1, 0, 0))
    degrees = range(10, 90, 10)
    learnt = [memory.learn_target(unit(np.cos(np.radians(d)), np.sin(np.radians(d)), 0)) for d in degrees]
    assert learnt == [d <= kept_up_to_degrees for d in degrees]
    last = memory.target_rows()[-1]
    assert np.degrees(np.arccos(np.clip(last[0], -1, 1))) == pytest.approx(kept_up_to_degrees, abs=1e-3)


class _MeanEmbedder:
    """Embeds each box as its frame region's mean level and the thread that computed it."""

    def __init__(self) -> None:
        self.threads: list[str] = []

    def embed(self, frame: np.ndarray, boxes_xywh: np.ndarray) -> np.ndarray:
        self.threads.append(threading.current_thread().name)
        return np.array([[frame[int(y):int(y + h), int(x):int(x + w)].mean()] for x, y, w, h in boxes_xywh],
                        np.float32)


@pytest.mark.parametrize("threaded", [False, True])
def test_deferred_embeddings_belong_to_the_frame_as_it_was_when_they_were_started(threaded):
    """The frame's owner may reuse its buffer once update() returns: the rows are those of the frame as given,
    computed once, on the worker when there is one and else on the first rows()."""
    embedder, frame = _MeanEmbedder(), np.full((40, 60, 3), 10, np.uint8)
    with concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="worker") as worker:
        job = DeferredEmbeddings(embedder, frame, np.array([[0.0, 0.0, 20.0, 20.0], [30.0, 10.0, 20.0, 20.0]]),
                                 worker if threaded else None)
        frame[:] = 200  # the owner reuses its buffer
        assert job.rows()[:, 0].tolist() == [10.0, 10.0]
        assert job.rows()[:, 0].tolist() == [10.0, 10.0]
    assert len(embedder.threads) == 1 and embedder.threads[0].startswith("worker") == threaded
