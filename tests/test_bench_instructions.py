"""bench.instructions' pure part: the per-call counts grouped by sequence and frame kind (no callgrind, no qemu)."""
import re

from bench.instructions import NestingCounter, summarise


def test_summarise_groups_by_sequence_and_kind_and_keeps_the_counts_in_frame_order():
    dumps = [("A|jsar|1", 10), ("A|jsar-re confident|1", 30), ("A|jsar|2", 14), ("A|jsar-re confident|2", 90),
             ("B|jsar|1", 7), ("A|jsar|3", 12)]
    summary = summarise(dumps)
    assert summary["A"]["jsar"] == {"frames": 3, "mean": 12.0, "median": 12, "max": 14, "counts": [10, 14, 12]}
    # a watch frame of jsar-re (the second here) stands out in the counts, not in the median
    assert summary["A"]["jsar-re confident"]["counts"] == [30, 90]
    assert summary["B"]["jsar"]["frames"] == 1
    # the segments of one label (a call counted inside it cut out) add up to one frame
    split = summarise([("A|jsar-re lost|1", 50), ("A|jsar|1", 20), ("A|jsar-re lost|1", 5), ("A|jsar-re lost|2", 40)])
    assert split["A"]["jsar-re lost"]["counts"] == [55, 40]


def test_a_lost_frames_three_parts_make_the_tracking_threads_count_and_the_critical_path():
    """The tracking thread's own work, its work beside the verifier's jobs and the jobs: "jsar-re lost" is the
    tracking thread's whole work, the critical path its own work plus the longer side of the parallel span."""
    parts = [("A|jsar-re lost, alone|1", 50), ("A|jsar-re lost, beside the verifier|1", 10),
             ("A|jsar-re lost, verifier thread|1", 30), ("A|jsar-re lost, alone|2", 40),
             ("A|jsar-re lost, beside the verifier|2", 25), ("A|jsar-re lost, verifier thread|2", 5)]
    summary = summarise(parts)["A"]
    assert summary["jsar-re lost"]["counts"] == [60, 65]
    assert summary["jsar-re lost, critical path"]["counts"] == [80, 65]
    assert summary["jsar-re lost, verifier thread"]["counts"] == [30, 5]
    assert "jsar-re lost, alone" not in summary and "jsar-re lost, beside the verifier" not in summary


def test_a_call_counted_inside_another_is_cut_out_of_it():
    """NestingCounter: every instruction counts once, under the innermost open label; the outer label's segments
    before and after the inner call are both its own (a fake counter: each segment is the events since the last)."""
    events: list[str] = []
    segments: list[tuple[str, list[str]]] = []
    since = [0]

    def begin() -> None:
        since[0] = len(events)

    def boundary(label: str) -> None:
        segments.append((label, events[since[0]:]))
        since[0] = len(events)

    counted = NestingCounter(begin, boundary)

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


def test_count_frame_kinds_counts_the_lost_frames_verifier_share_apart(data_root):
    """share_lost_work: the lost frames' tracker has a verifier worker (bench.instructions.CountedWorker): the frame's
    work from a job's start to its result and the job itself are counted apart from the rest of the frame, each
    part once more after every lost frame (a frame that gave the worker nothing counts 0 there)."""
    from bench.instructions import LOST_PARTS, count_frame_kinds

    segments: list[str] = []
    counted = NestingCounter(lambda: None, segments.append)
    states = count_frame_kinds(data_root, "OTB_Crossing", 2, 6, counted, share_lost_work=True)
    lost = [label for label in segments if "jsar-re lost" in label]
    assert {label.split("|")[1] for label in lost} == set(LOST_PARTS)
    for index in range(3, 9):
        assert [label for label in lost if label.endswith(f"|{index}")][-3:] == [
            f"OTB_Crossing|{part}|{index}" for part in LOST_PARTS]  # the closing three
    # a job within the second frame (the first is tracked until its loss is declared, with no worker): the frame's
    # own work, its work beside the job up to the job's result, the job, the frame's own again
    parts = [label.split("|")[1] for label in lost if label.endswith("|4")]
    assert parts[:5] == [LOST_PARTS[0], LOST_PARTS[1], LOST_PARTS[0], LOST_PARTS[2], LOST_PARTS[0]]
    assert states == ["lost"] * 6
