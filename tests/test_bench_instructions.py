"""bench.instructions' pure part: the per-call counts grouped by sequence and frame kind (no callgrind, no qemu)."""
import re

from bench.instructions import NestingCounter, lost_frame_times, summarise


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


def test_a_lost_frames_jobs_are_replayed_on_one_worker_for_the_critical_path():
    """lost_frame_times: the tracking thread's work, the jobs', and the tracking thread's time to the frame's end when
    the jobs run one at a time in submit order beside it and a result waits for its job."""
    assert lost_frame_times([("jsar-re lost", 50)]) == (50, 0, 50)  # no job: the frame is the tracking thread's
    # a job submitted at 10, asked for at 30, done at 10 + 30 = 40: the thread waits 10, then 5 more
    assert lost_frame_times([("jsar-re lost", 10), ("jsar-re lost, submit 1", 0), ("jsar-re lost", 20),
                             ("jsar-re lost, result 1", 0), ("jsar-re lost, job 1", 30),
                             ("jsar-re lost", 5)]) == (35, 30, 45)
    # a coast's commit (40) queued first: the windows' job (20) submitted at 10 waits for it (40 -> 60), not
    # beside it; the commit, asked for last, is long done
    assert lost_frame_times([("jsar-re lost, submit 1", 0), ("jsar-re lost", 10), ("jsar-re lost, submit 2", 0),
                             ("jsar-re lost", 30), ("jsar-re lost, result 2", 0), ("jsar-re lost, job 2", 20),
                             ("jsar-re lost", 10), ("jsar-re lost, result 1", 0), ("jsar-re lost, job 1", 40),
                             ("jsar-re lost", 5)]) == (55, 60, 75)
    # a job nobody asks for (a deferred watch check, counted at the frame's end) holds the worker from 5 to 105
    assert lost_frame_times([("jsar-re lost", 5), ("jsar-re lost, submit 1", 0), ("jsar-re lost", 10),
                             ("jsar-re lost, submit 2", 0), ("jsar-re lost, result 2", 0), ("jsar-re lost, job 2", 10),
                             ("jsar-re lost", 1), ("jsar-re lost, job 1", 100)]) == (16, 110, 116)


def test_summarise_gives_every_lost_frame_of_a_shared_count_its_three_kinds():
    """A sequence counted with a worker: each lost frame's tracking thread, worker and critical path (a frame that
    gave the worker nothing: 0 and its own work); the job events are no kind of their own."""
    dumps = [("A|jsar|1", 7), ("A|jsar-re lost|2", 30), ("A|jsar-re lost, submit 1|2", 1), ("A|jsar-re lost|2", 2),
             ("A|jsar-re lost, result 1|2", 1), ("A|jsar-re lost, job 1|2", 20), ("A|jsar-re lost|2", 6),
             ("A|jsar-re lost|3", 40)]
    summary = summarise(dumps)["A"]
    assert summary["jsar-re lost"]["counts"] == [40, 40]
    assert summary["jsar-re lost, verifier thread"]["counts"] == [20, 0]
    assert summary["jsar-re lost, critical path"]["counts"] == [57, 40]  # 31 + wait to 51, + 6
    assert set(summary) == {"jsar", "jsar-re lost", "jsar-re lost, verifier thread", "jsar-re lost, critical path"}


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


def test_count_frame_kinds_counts_the_lost_frames_jobs_and_their_events(data_root):
    """share_lost_work: the lost frames' tracker has a verifier worker (bench.instructions.CountedWorker) from the
    first hidden frame on: each job's submission and result are marked in the frame's own count, the job is counted
    apart, under the frame's number, and summarise replays them (every frame has its three kinds)."""
    from bench.instructions import LOST_EVENT, count_frame_kinds

    segments: list[str] = []
    counted = NestingCounter(lambda: None, segments.append)
    states = count_frame_kinds(data_root, "UAV123_10fps_wakeboard10", 2, 8, counted, share_lost_work=True)
    assert states == ["lost"] * 8
    lost = [label for label in segments if "jsar-re lost" in label]
    events = [(m.group(1), int(m.group(2)), label.split("|")[2]) for label in lost
              if (m := LOST_EVENT.match(label.split("|")[1]))]
    assert events, "no lost frame gave the worker a job"
    for kind, number, frame in events:
        if kind == "result":  # asked for: its job is counted right after, within the same frame
            assert f"UAV123_10fps_wakeboard10|jsar-re lost, job {number}|{frame}" in lost
        assert ("submit", number, frame) in events  # every job event follows its submission, in its frame
    summary = summarise([(label, 1) for label in segments])["UAV123_10fps_wakeboard10"]
    assert summary["jsar-re lost, critical path"]["frames"] == summary["jsar-re lost"]["frames"] == 8
