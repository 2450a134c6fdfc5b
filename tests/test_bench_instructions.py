"""bench.instructions' pure part: the per-call counts grouped by sequence and frame kind (no callgrind, no qemu)."""
from bench.instructions import summarise


def test_summarise_groups_by_sequence_and_kind_and_keeps_the_counts_in_frame_order():
    dumps = [("A|jsar|1", 10), ("A|jsar-re confident|1", 30), ("A|jsar|2", 14), ("A|jsar-re confident|2", 90),
             ("B|jsar|1", 7), ("A|jsar|3", 12)]
    summary = summarise(dumps)
    assert summary["A"]["jsar"] == {"frames": 3, "mean": 12.0, "median": 12, "max": 14, "counts": [10, 14, 12]}
    # a watch frame of jsar-re (the second here) stands out in the counts, not in the median
    assert summary["A"]["jsar-re confident"]["counts"] == [30, 90]
    assert summary["B"]["jsar"]["frames"] == 1


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
