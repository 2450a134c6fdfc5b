"""Spatial robustness evaluation (jsar.eval.sre, `python -m jsar.eval --starts`): the perturbed initial boxes,
their scores and spread with a tracker that never moves, the JSON, the CLI's checks, the process pool."""
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from jsar.api import TrackResult
from jsar.eval import dataset, evaluate, longterm, report, sre
from jsar.eval.runner import run_indexed
from jsar.eval.synthetic import synthetic_clip, write_otb_sequence

REPO = Path(__file__).resolve().parents[1]
FRAME_HW = (240, 320)
LARGE = (60.0, 50.0, 220.0, 100.0)  # shift10 in x = 22 px > 20 px: precision 0 there; in y 10 px: 1
SMALL = (40.0, 30.0, 50.0, 30.0)  # every start's centre within 20 px: precision 1


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "jsar.eval", *args, "--no-progress"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


class Still:
    """A tracker that reports its initial box on every frame."""

    def init(self, frame, box):
        self.box = tuple(box)

    def update(self, frame):
        return TrackResult(self.box, 1.0, "tracking")


def static_sequence(folder, box, n_frames=4):
    """An OTB folder of grey noise frames whose ground truth is `box` on every frame."""
    rng = np.random.default_rng(0)
    frames = [rng.integers(60, 200, (*FRAME_HW, 3), dtype=np.uint8) for _ in range(n_frames)]
    return dataset.load_sequence(write_otb_sequence(folder, frames, np.array([box] * n_frames)))


def test_perturbed_boxes_are_the_specified_ones():
    box = np.array([40.0, 30.0, 50.0, 30.0])  # centre (65, 45)
    expected = {
        "exact": [40, 30, 50, 30],
        "shift2_+x+y": [42, 32, 50, 30], "shift2_+x-y": [42, 28, 50, 30],
        "shift2_-x+y": [38, 32, 50, 30], "shift2_-x-y": [38, 28, 50, 30],
        "shift10_-x": [35, 30, 50, 30], "shift10_+x": [45, 30, 50, 30],
        "shift10_-y": [40, 27, 50, 30], "shift10_+y": [40, 33, 50, 30],
        "scale0.9": [42.5, 31.5, 45, 27], "scale1.1": [37.5, 28.5, 55, 33],
    }
    assert [s.name for s in sre.SRE_STARTS] == list(expected)
    assert [s.index for s in sre.SRE_STARTS] == list(range(11))
    for start in sre.SRE_STARTS:
        np.testing.assert_allclose(sre.start_box(box, start, (*FRAME_HW, 3)), expected[start.name], atol=1e-9,
                                   err_msg=start.name)


def test_perturbed_boxes_are_clipped_at_the_frame_border():
    shape = (*FRAME_HW, 3)
    corner = np.array([0.0, 1.0, 50.0, 30.0])  # at the top-left corner
    by_name = {s.name: s for s in sre.SRE_STARTS}
    np.testing.assert_allclose(sre.start_box(corner, by_name["shift2_-x-y"], shape), [0, 0, 48, 29])
    np.testing.assert_allclose(sre.start_box(corner, by_name["shift10_-x"], shape), [0, 1, 45, 30])
    np.testing.assert_allclose(sre.start_box(corner, by_name["scale1.1"], shape), [0, 0, 52.5, 32.5])
    np.testing.assert_allclose(sre.start_box(corner, by_name["shift2_+x+y"], shape), [2, 3, 50, 30])  # inside
    far = np.array([270.0, 210.0, 50.0, 30.0])  # touching the right and bottom borders
    np.testing.assert_allclose(sre.start_box(far, by_name["shift2_+x+y"], shape), [272, 212, 48, 28])
    np.testing.assert_allclose(sre.start_box(far, by_name["shift10_+y"], shape), [270, 213, 50, 27])
    outside = np.array([-3.0, 0.0, 20.0, 10.0])  # the exact box is never changed, even beyond the border
    np.testing.assert_allclose(sre.start_box(outside, sre.EXACT, shape), outside)
    with pytest.raises(ValueError, match="lies outside the 320x240 frame"):
        sre.clipped(np.array([330.0, 10.0, 5.0, 5.0]), 320, 240)


@pytest.mark.parametrize(("text", "indices"), [
    ("exact", [0]), ("sre", list(range(11))), ("sre:0,2,5,9", [0, 2, 5, 9]), ("sre:9, 0", [0, 9]),
])
def test_parse_starts(text, indices):
    assert [s.index for s in sre.parse_starts(text)] == indices


@pytest.mark.parametrize(("text", "message"), [
    ("all", "expected exact, sre (all 11 starts) or sre:I,J,..."),
    ("sre:2,5", "leaves out 0 (exact)"),
    ("sre:0,11", "index 11 out of range 0-10"),
    ("sre:0,x", "indices must be integers 0-10"),
    ("sre:0,3,3", "an index is given twice"),
    ("sre:", "indices must be integers"),
])
def test_parse_starts_rejects(text, message):
    with pytest.raises(ValueError, match=message.replace(".", r"\.").replace("(", r"\(").replace(")", r"\)")):
        sre.parse_starts(text)


def test_a_still_tracker_scores_each_start_as_its_overlap_and_the_spread_is_computed_over_starts(tmp_path):
    seqs = [static_sequence(tmp_path / "large", LARGE), static_sequence(tmp_path / "small", SMALL)]
    result = evaluate.evaluate(seqs, ["still"], factories={"still": Still}, starts=sre.SRE_STARTS)
    names = [s.name for s in sre.SRE_STARTS]
    # Every frame has the start's box, so AUC = (success thresholds 0, 0.05, .. 1 below its IoU) / 21.
    # LARGE: exact IoU 1 -> 20; diagonal 2 px 0.944 -> 19; shift10 x or y 0.818, scale0.9 0.81, scale1.1 0.826 -> 17.
    # SMALL: exact 20; diagonal 0.812 -> 17; the rest as LARGE's -> 17.
    auc_large = np.array([20, 19, 19, 19, 19, 17, 17, 17, 17, 17, 17]) / 21
    auc_small = np.array([20] + [17] * 10) / 21
    prec_large = np.array([1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1], float)  # shift10_x moves the centre 22 px
    section = result["sre"]
    for seq, aucs, precs in (("large", auc_large, prec_large), ("small", auc_small, np.ones(11))):
        starts = section["sequences"][seq]["starts"]
        assert [starts[n]["trackers"]["still"]["auc"] for n in names] == pytest.approx(aucs)
        assert [starts[n]["trackers"]["still"]["precision"] for n in names] == pytest.approx(precs)
        np.testing.assert_allclose(starts["scale1.1"]["trackers"]["still"]["boxes"][1], starts["scale1.1"]["box"])
    large = section["sequences"]["large"]["trackers"]["still"]
    assert large["auc"]["mean"] == pytest.approx(6 / 7)  # (20 + 4 * 19 + 6 * 17) / 21 / 11
    assert large["auc"]["std"] == pytest.approx(np.sqrt(14 / 11) / 21)  # deviations 2, 1 x 4, -1 x 6 (/21)
    assert (large["auc"]["min"], large["auc"]["max"], large["auc"]["exact"]) == pytest.approx(
        (17 / 21, 20 / 21, 20 / 21))
    p = 9 / 11
    assert (large["precision"]["mean"], large["precision"]["std"]) == pytest.approx((p, np.sqrt(p * (1 - p))))
    assert (large["precision"]["min"], large["precision"]["exact"]) == (0.0, 1.0)
    # The set: per start the mean over the two sequences, then the spread over the starts.
    per_start = section["summary"]["still"]["per_start"]
    set_auc = (auc_large + auc_small) / 2
    assert [per_start[n]["auc"] for n in names] == pytest.approx(set_auc)
    assert per_start["shift10_+x"]["precision"] == 0.5 and per_start["shift10_+y"]["precision"] == 1.0
    whole = section["summary"]["still"]["auc"]
    assert (whole["mean"], whole["std"]) == pytest.approx((set_auc.mean(), set_auc.std()))
    assert whole["exact"] == pytest.approx(20 / 21) == result["summary"]["still"]["auc"]
    # "sequences" / "summary" stay the exact start's, as without --starts.
    assert result["sequences"]["large"]["trackers"]["still"]["boxes"][0].tolist() == list(LARGE)
    assert result["summary"]["still"]["precision"] == 1.0
    assert "sre" not in evaluate.evaluate(seqs, ["still"], factories={"still": Still})
    table = report.format_sre_tables(result)
    assert "0.857 ±0.054 [0.810, 0.952] 0.952" in table  # large's AUC row: 6/7, sqrt(14/11)/21, 17/21, 20/21


def test_longterm_every_start_sees_the_same_events_and_reports_the_rates(tmp_path):
    frames, boxes = synthetic_clip(n_frames=40, size=FRAME_HW, object_size=(30, 24), seed=3)
    seq = dataset.load_sequence(write_otb_sequence(tmp_path / "syn", frames, boxes))
    config = longterm.InjectionConfig(first_start=5, gap_after=4)
    starts = sre.parse_starts("sre:0,4,10")
    result = evaluate.evaluate_longterm([seq], ["still"], ["occlusion"], (3, 6), seed=1, config=config,
                                        factories={"still": Still}, starts=starts)
    run = result["sre"]["sequences"]["syn+occlusion"]
    spans = {name: [(e["start"], e["length"]) for e in s["trackers"]["still"]["longterm"]["events"]]
             for name, s in run["starts"].items()}
    assert list(spans) == ["exact", "shift2_-x-y", "scale1.1"]
    assert spans["exact"] == spans["shift2_-x-y"] == spans["scale1.1"]
    assert sorted(length for _, length in spans["exact"]) == [3, 6]
    figures = result["sre"]["summary"]["still"]
    lt = result["summary"]["still"]["longterm"]
    for key in sre.LONGTERM_METRICS:
        assert figures[key]["exact"] == lt[key]
        assert figures[key]["n"] == 3
    # A box that never moves is never "recovered" nor jumps while the target is absent, and says "tracking".
    assert figures["false_reinit_rate"]["max"] == 0.0 and figures["absent_reported_lost_rate"]["max"] == 0.0
    assert "re-acquired: mean ±sd [min, max] exact" in report.format_sre_tables(result)


def test_jobs_give_the_same_result_as_one_process(tmp_path):
    seqs = [static_sequence(tmp_path / "large", LARGE), static_sequence(tmp_path / "small", SMALL)]
    starts = sre.parse_starts("sre:0,1,9")
    frames_done = []
    one = evaluate.evaluate(seqs, ["still"], factories={"still": Still}, starts=starts)
    two = evaluate.evaluate(seqs, ["still"], factories={"still": Still}, starts=starts, jobs=2,
                            progress=frames_done.append)
    assert sorted(frames_done) == [4] * 6  # one report per (sequence, start) run, its frames
    for seq in ("large", "small"):
        for name in ("exact", "shift2_+x+y", "scale0.9"):
            a = one["sre"]["sequences"][seq]["starts"][name]["trackers"]["still"]
            b = two["sre"]["sequences"][seq]["starts"][name]["trackers"]["still"]
            np.testing.assert_array_equal(a["boxes"], b["boxes"])
            assert a["auc"] == b["auc"]


def _worker_facts(index, on_frame):
    from threadpoolctl import threadpool_info
    return os.getpid(), index, cv2.getNumThreads(), [p["num_threads"] for p in threadpool_info()]


def test_pool_workers_are_other_processes_with_one_thread():
    results = run_indexed(_worker_facts, [1, 1, 1, 1], jobs=2)
    assert [r[1] for r in results] == [0, 1, 2, 3]  # in index order
    assert all(pid != os.getpid() for pid, *_ in results)
    assert all(cv2_threads == 1 and all(n == 1 for n in pools) for _, _, cv2_threads, pools in results)
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        run_indexed(_worker_facts, [1], jobs=0)

    def fails(index, on_frame):
        raise ValueError(f"task {index} failed")
    with pytest.raises(ValueError, match="failed"):
        run_indexed(fails, [1, 1], jobs=2)


def test_cli_starts_writes_per_start_json_and_rejects_bad_values(tmp_path):
    static_sequence(tmp_path / "data" / "large", LARGE, n_frames=6)
    out = tmp_path / "r.json"
    proc = run_cli(str(tmp_path / "data"), "--trackers", "kcf", "--starts", "sre:0,9", "--jobs", "2",
                   "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "Spatial robustness: 2 initial boxes (0 exact, 9 scale0.9)" in proc.stdout
    result = json.loads(out.read_text())
    assert result["starts"] == "sre:0,9" and result["jobs"] == 2
    starts = result["sre"]["sequences"]["large"]["starts"]
    assert list(starts) == ["exact", "scale0.9"]
    assert starts["scale0.9"]["box"] == pytest.approx([71.0, 55.0, 198.0, 90.0])
    assert starts["scale0.9"]["trackers"]["kcf"]["boxes"][0] == pytest.approx([71.0, 55.0, 198.0, 90.0])
    assert len(starts["scale0.9"]["trackers"]["kcf"]["states"]) == 6
    exact = result["sequences"]["large"]["trackers"]["kcf"]
    assert exact["boxes"][0] == list(LARGE) and exact["auc"] == starts["exact"]["trackers"]["kcf"]["auc"]
    assert result["sre"]["summary"]["kcf"]["auc"]["exact"] == result["summary"]["kcf"]["auc"]
    for bad, message in (("sre:3", "--starts 'sre:3' leaves out 0 (exact)"), ("many", "--starts: expected exact"),
                         ("sre:0,12", "index 12 out of range 0-10")):
        proc = run_cli(str(tmp_path / "data"), "--trackers", "kcf", "--starts", bad)
        assert proc.returncode != 0 and message in proc.stderr, proc.stderr
    proc = run_cli(str(tmp_path / "data"), "--trackers", "kcf", "--jobs", "0")
    assert proc.returncode != 0 and "--jobs must be >= 1, got 0" in proc.stderr
