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
