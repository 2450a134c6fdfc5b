"""bench.instructions' pure part: the per-call counts grouped by sequence and frame kind (no callgrind, no qemu)."""
import re

from bench.instructions import nesting_counter, summarise


def test_summarise_groups_by_sequence_and_kind_and_keeps_the_counts_in_frame_order():
    dumps = [("A|jsar|1", 10), ("A|jsar-re confident|1", 30), ("A|jsar|2", 14), ("A|jsar-re confident|2", 90),
             ("B|jsar|1", 7), ("A|jsar|3", 12)]
    summary = summarise(dumps)
    assert summary["A"]["jsar"] == {"frames": 3, "mean": 12.0, "median": 12, "max": 14, "counts": [10, 14, 12]}
    # a watch frame of jsar-re (the second here) stands out in the counts, not in the median
    assert summary["A"]["jsar-re confident"]["counts"] == [30, 90]
    assert summary["B"]["jsar"]["frames"] == 1
    # the segments of one label (a call counted inside it cut out) add up to one frame
    split = summarise([("A|jsar-re lost|1", 50), ("A|jsar-re lost, verifier thread|1", 20), ("A|jsar-re lost|1", 5),
                       ("A|jsar-re lost, verifier thread|1", 0), ("A|jsar-re lost|2", 40)])
    assert split["A"]["jsar-re lost"]["counts"] == [55, 40]
    assert split["A"]["jsar-re lost, verifier thread"]["counts"] == [20]


def test_a_call_counted_inside_another_is_cut_out_of_it():
    """nesting_counter: every instruction counts once, under the innermost open label; the outer label's segments
    before and after the inner call are both its own (a fake counter: each segment is the events since the last)."""
    events: list[str] = []
    segments: list[tuple[str, list[str]]] = []
    since = [0]

    def begin() -> None:
        since[0] = len(events)

    def boundary(label: str) -> None:
        segments.append((label, events[since[0]:]))
        since[0] = len(events)

    counted = nesting_counter(begin, boundary)

    def frame() -> str:
        events.append("locate")
        counted("verifier", lambda: events.append("embed"))
        events.append("commit")
        return "done"

    assert counted("frame", frame) == "done"
    assert segments == [("frame", ["locate"]), ("verifier", ["embed"]), ("frame", ["commit"])]
    counted("frame2", lambda: events.append("next"))
    assert segments[-1] == ("frame2", ["next"])


def test_count_frame_kinds_labels_every_measured_call_of_both_benchmarks(data_root):
    """The per-sequence set-up bench.instructions and bench.profile share: each kind on each tracked frame (jsar-re's
    deferred verifier work counted apart, as the service's verifier thread does it), then jsar-re's lost frames with the target hidden (what a lost frame costs only if they are lost)."""
    from bench.instructions import count_frame_kinds

    labels: list[str] = []

    def counted(label, call):
        labels.append(label)
        call()

    states = count_frame_kinds(data_root, "OTB_Crossing", 2, 2, counted)
    assert labels == ["OTB_Crossing|jsar|1", "OTB_Crossing|csrt|1", "OTB_Crossing|kcf|1",
                      "OTB_Crossing|jsar-re confident|1", "OTB_Crossing|jsar-re verifier|1",
                      "OTB_Crossing|jsar|2", "OTB_Crossing|csrt|2", "OTB_Crossing|kcf|2",
                      "OTB_Crossing|jsar-re confident|2", "OTB_Crossing|jsar-re verifier|2",
                      "OTB_Crossing|jsar-re lost|3", "OTB_Crossing|jsar-re lost|4"]
    assert states == ["lost", "lost"]


def test_count_frame_kinds_counts_the_lost_frames_verifier_share_inside_the_frame(data_root):
    """share_lost_work: the lost frames' tracker has a verifier worker (bench.instructions.CountedWorker) whose jobs
    (turned windows' features, looks after the first) are counted inside the frame's call under the verifier
    thread's kind, and that kind once more after every lost frame (a frame that gave it nothing counts 0)."""
    from bench.instructions import count_frame_kinds

    calls: list[tuple[int, str]] = []
    depth = [0]

    def counted(label, call):
        calls.append((depth[0], label))
        depth[0] += 1
        try:
            return call()
        finally:
            depth[0] -= 1

    states = count_frame_kinds(data_root, "OTB_Crossing", 2, 6, counted, share_lost_work=True)
    lost = [(d, label) for d, label in calls if "jsar-re lost" in label]
    assert [label for d, label in lost if d == 0] == [
        label for index in range(3, 9) for label in (f"OTB_Crossing|jsar-re lost|{index}",
                                                     f"OTB_Crossing|jsar-re lost, verifier thread|{index}")]
    inside = [label for d, label in lost if d == 1]
    assert inside and all(re.fullmatch(r"OTB_Crossing\|jsar-re lost, verifier thread\|[3-8]", label) for label in inside)
    assert states == ["lost"] * 6


def test_the_searching_tracker_takes_a_variants_overrides_and_keeps_its_own_warm_up_and_hold_off():
    """--params counts a variant: its overrides reach jsar-re, while the searching tracker's warm-up 0 and endless
    hold-off (every lost frame spends its whole budget) win over them."""
    from bench.redetect import searching_tracker

    overrides = {"redetect": {"verify": {"lost_looks": 1}, "accept": {"holdoff_frames": 2, "confirm_frames": 3}}}
    tracker = searching_tracker(overrides=overrides)
    assert tracker.redetect.verify.lost_looks == 1 and tracker.redetect.accept.confirm_frames == 3
    assert tracker.redetect.accept.holdoff_frames == 10**9 and tracker.redetect.monitor.warmup_frames == 0
    assert overrides["redetect"]["accept"]["holdoff_frames"] == 2  # the caller's dict is left as it was
    assert searching_tracker(4).redetect.search.windows_per_frame == 4
