"""bench.ceiling on a tiny synthetic sequence: the probe leaves the tracker's run as jsar.eval's long-term
protocol has it, and the oracle's window recognises the target where it is and nowhere else."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import jsar
from bench import ceiling
from jsar.eval import dataset, evaluate, longterm
from jsar.eval.synthetic import synthetic_clip, write_otb_sequence
from jsar.redetect.jsar_re import Phase

N_FRAMES = 60  # one 5-frame event after the protocol's first 30 frames and before its 15-frame gap


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> dataset.Sequence:
    root = tmp_path_factory.mktemp("otb")
    frames, boxes = synthetic_clip(n_frames=N_FRAMES, size=(120, 160), object_size=(20, 16), seed=4)
    write_otb_sequence(root / "syn", frames, boxes)
    return dataset.load_sequence(root / "syn")


def test_the_probe_only_reads_the_tracker(sequence):
    """The same boxes' scores as jsar.eval's long-term run of jsar-re on the same events: the oracle's
    windows change nothing the tracker does; the events re-acquired there are within reach here."""
    events = longterm.inject_events(sequence, "occlusion", (5,), seed=0)
    assert events.events, "the synthetic sequence must hold one event"
    probed = ceiling.run_sequence(events, window=15, needed=2)
    reference = evaluate.evaluate_longterm([sequence], ["jsar-re"], ["occlusion"], (5,), 0)
    run = reference["sequences"][events.name]["trackers"]["jsar-re"]["longterm"]
    for key in ("n_reacquired", "false_reinit_absent", "false_reinit_wrong_object", "absent_reported_lost"):
        assert probed[key] == run[key], key
    for event in probed["events"]:
        if event["reacquired"]:
            assert event["reach_tracker"] and event["reach_groundtruth"]


def test_the_oracle_recognises_the_target_and_not_the_background(sequence):
    """Right after init the decision filter knows the target: a window on the ground truth passes the
    candidate's tests; the same window on the background in a corner, over 3 sides away, does not."""
    tracker = jsar.create("jsar-re")
    first = sequence.read_frame(0)
    tracker.init(first, tuple(float(v) for v in sequence.groundtruth[0]))
    frame, box = sequence.read_frame(1), np.array(sequence.groundtruth[1], dtype=float)
    tracker.update(frame)
    side = float(np.sqrt(box[2] * box[3]))
    assert ceiling.oracle_recognises(tracker, frame, box, frames_since=1, side_px=side)
    corner = np.array([2.0, 2.0, box[2], box[3]])  # the top-left corner's background
    assert np.hypot(*(box[:2] - corner[:2])) > 3 * side, "the synthetic target must lie away from the corner"
    assert not ceiling.oracle_recognises(tracker, frame, corner, frames_since=1, side_px=side)


def test_the_oracle_search_takes_nothing_while_the_target_is_absent(sequence):
    """With the search given only the target's windows ("oracle"), no loss ends while the target is
    hidden: no frame of the event is "recovered" and none is counted as a false re-initialisation."""
    events = longterm.inject_events(sequence, "occlusion", (5,), seed=0)
    scores = ceiling.run_sequence(events, window=15, needed=2, search="oracle")
    assert scores["false_reinit_absent"] == 0 and scores["false_reinit_wrong_object"] == 0
    assert not any(event["took_during_event"] for event in scores["events"])
    assert all(event["outcome"] != "took during absence" for event in scores["events"])


def test_the_oracle_search_scores_the_target_only_while_lost_and_visible(sequence):
    """The oracle tracker's extra windows are centred on the ground truth, and none is scored while the
    target is absent."""
    tracker = ceiling.OracleSearchTracker("oracle")
    frame = sequence.read_frame(0)
    tracker.init(frame, tuple(float(v) for v in sequence.groundtruth[0]))
    tracker.loss = tracker._new_loss()
    tracker.phase = Phase.LOST
    own = tracker._score_core_sample(tracker.core.locate(frame))
    tracker.groundtruth_box = np.full(4, np.nan)
    assert tracker._candidates(frame, tracker.loss, own) == [dataclasses.replace(own, score=0.0)]
    box = np.array(sequence.groundtruth[0], dtype=float)
    tracker.groundtruth_box = box
    found = tracker._candidates(frame, tracker.loss, tracker._score_core_sample(tracker.core.locate(frame)))
    centre = box[:2] + box[2:] / 2.0
    windows = [c.window_xy for c in found[1:]]
    assert len(windows) == 1 + len(tracker.redetect.search.turned_angles_deg)
    assert all(np.allclose(w, centre) for w in windows)


def test_the_command_line_writes_the_counts_and_names_a_wrong_sequence(sequence, tmp_path, capsys):
    """`python -m bench.ceiling ROOT --search oracle --json F`: the summary line and the JSON's counts agree
    with the events it lists; a sequence not under ROOT is an error naming it."""
    root = Path(sequence.frame_paths[0]).parents[1].parent
    out = tmp_path / "ceiling.json"
    assert ceiling.main([str(root), "--search", "oracle", "--kinds", "occlusion", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["search"] == "oracle" and written["summary"]["events"] == len(written["events"]) >= 1
    assert written["summary"]["reacquired"] == sum(e["reacquired"] for e in written["events"])
    assert f"{written['summary']['events']} events" in capsys.readouterr().out
    assert ceiling.main(["--from-json", str(out)]) == 0
    missed = written["summary"]["events"] - written["summary"]["reacquired"]
    assert capsys.readouterr().out.startswith(f"missed {missed}:")
    with pytest.raises(SystemExit):
        ceiling.main([str(root), "--sequences", "nowhere"])
    assert "nowhere" in capsys.readouterr().err


def test_a_miss_is_put_down_to_the_first_reason_that_holds():
    """Tracking something else at the return comes first; then the oracle's window under the bar on every
    frame; then the colour check refusing it wherever place and bar passed; anything else is "other"."""
    base = {"reacquired": False, "reach_tracker": False, "state_at_return": "lost", "best_score_over_bar": 1.3,
            "recognised_frames_tracker": 0,
            "failed_tests": {"place": 0, "bar": 0, "colour": 15}, "took_during_event": False,
            "target_for_search": {"outside gate": 2, "outside lattice": 2, "inside lattice": 0, "first ring": 1}}
    def reason(entry: dict) -> str:
        return ceiling.miss_reason(ceiling.ProbedEvent.from_json(entry))

    assert reason(base) == "colour"
    assert reason(base | {"state_at_return": "tracking", "best_score_over_bar": 0.5}) == "tracking"
    assert reason(base | {"best_score_over_bar": 0.9}) == "bar"
    assert reason(base | {"recognised_frames_tracker": 1}) == "other"
    assert reason(base | {"failed_tests": {"place": 1, "bar": 0, "colour": 14}}) == "other"
    assert ceiling.lay_most(ceiling.ProbedEvent.from_json(base)) == "outside gate"  # a tie: the farther place
    line = ceiling.miss_breakdown([ceiling.ProbedEvent.from_json(e) for e in
                                   (base, base | {"best_score_over_bar": 0.6}, base | {"reacquired": True})])
    assert line.startswith("missed 2:") and "under the bar on every frame 1 " in line
    assert "outside gate 2 (0 within reach)" in line
