"""Held-out UAV sequences: a manifest for the shared data tool, never used for a tracker decision.

Issue 15's fourteen rounds of decisions were all measured on *more* (12 sequences), so *more* is no
longer fresh. These sequences were listed after the last of those decisions and are scored once per
tracker change, to see whether what was measured on *more* holds on video nobody tuned on. Do not
tune on them; when a decision needs more data, add sequences to a new held-out list instead.

Make them (frames and ground truth stay outside the repository):

    python3 ../shared/tools/get_more_data.py --list-repos --manifest bench/heldout_sequences.py
    # fetch each printed snapshot with the search tool's `fetch`, then
    python3 ../shared/tools/get_more_data.py MIRROR_DIR ~/uav-heldout --manifest bench/heldout_sequences.py

Record format: the tool's own `MANIFEST` (1-based inclusive frame ranges into the sorted frame
names; UAV123 sub-sequences share their boundary frame). All UAV123@10fps. The first seven (listed
2026-12-04) have no absent frames; the nine added on 2026-12-05 include five with the benchmark's own
absent (NaN) runs, which the long-term protocol scores as real events: car14, group2_1, group2_2,
group2_3, person12_2. Where a repository ships the frames without the sub-sequence's annotation, the
annotation comes from the UAV123@10fps toolkit copy in JinJinSang/Tools-Package-for-UAV-Tracking.
group1_1 is another part of the flight whose group1_3 is in *more* (same people, other frames).
car16_1 / car16_2 were left out: their annotations have one line fewer than the toolkit's frame ranges.
"""

TITLE = "held-out (never used for a decision)"

_ARCF = dict(repo="vision4robotics/ARCF-tracker", commit="35ba2cc88024edfa76079048c61fc8cc1ea67e4b")
_OMFL = dict(repo="vision4robotics/OMFL-Tracker", commit="ebaf93201a990c46b9bdddd1f8953676c0298ec0")
_BEVT = dict(repo="vision4robotics/BEVT-tracker", commit="ace0787614cac8e4460a1cf8862661b28170b112")
_BICF = dict(repo="vision4robotics/BiCF-Tracker", commit="762d5e8ec6a4cb6b70a31daf6548759f4e71e034")
_TSD = dict(repo="vision4robotics/TSD-Tracker", commit="4eb7f42993a6d71c50eba03727a05e49d111c68c")
_CPCF = dict(repo="vision4robotics/CPCF-Tracker", commit="c41fcd6344b62f27028a24193be944ced9fccd7b")
_RESL = dict(repo="Van23Li/ReSL-tracker", commit="61aa09e4115b6ece0695dc5495a699029ee82135")
_TOOLKIT = ("JinJinSang/Tools-Package-for-UAV-Tracking", "7c60898e3772794ad1610fa30e760c680b28986e")
_TOOLKIT_ANNO = "Benchmark_UAV123_10fps/anno/UAV123_10fps/"

MANIFEST = [
    dict(name="UAV123_10fps_boat1", benchmark="UAV123@10fps", **_ARCF,
         frames="seq/boat1", first=1, last=301, expected=301, gt=["seq/boat1.txt"]),
    dict(name="UAV123_10fps_building4", benchmark="UAV123@10fps", **_ARCF,
         frames="seq/building4", first=1, last=263, expected=263, gt=["seq/building4.txt"]),
    dict(name="UAV123_10fps_person12_1", benchmark="UAV123@10fps", **_ARCF,
         frames="seq/person12", first=1, last=201, expected=201, gt=["seq/person12_1.txt"]),
    dict(name="UAV123_10fps_truck4_1", benchmark="UAV123@10fps", **_ARCF,
         frames="seq/truck4", first=1, last=193, expected=193, gt=["seq/truck4_1.txt"]),
    dict(name="UAV123_10fps_truck4_2", benchmark="UAV123@10fps", **_ARCF,
         frames="seq/truck4", first=193, last=421, expected=229, gt=["seq/truck4_2.txt"]),
    dict(name="UAV123_10fps_building5", benchmark="UAV123@10fps", **_OMFL,
         frames="UAV123_10fps/data_seq/building5", first=1, last=161, expected=161,
         gt=["UAV123_10fps/anno/building5.txt"]),
    dict(name="UAV123_10fps_group1_1", benchmark="UAV123@10fps", **_OMFL,
         frames="UAV123_10fps/data_seq/group1", first=1, last=445, expected=445,
         gt=["UAV123_10fps/anno/group1_1.txt"]),
    dict(name="UAV123_10fps_boat4", benchmark="UAV123@10fps", **_RESL,
         frames="UAV123_10fps/data_seq/boat4", first=1, last=185, expected=185,
         gt=["UAV123_10fps/anno/boat4.txt"]),
    dict(name="UAV123_10fps_car14", benchmark="UAV123@10fps", **_BEVT,
         frames="seq/car14", first=1, last=443, expected=443, gt=["seq/car14.txt"]),
    dict(name="UAV123_10fps_wakeboard4", benchmark="UAV123@10fps", **_BEVT,
         frames="seq/wakeboard4", first=1, last=233, expected=233, gt=["seq/wakeboard4.txt"]),
    dict(name="UAV123_10fps_person11", benchmark="UAV123@10fps", **_BICF,
         frames="sequences/person11/img", first=1, last=241, expected=241,
         gt=["sequences/person11/groundtruth_rect.txt"]),
    dict(name="UAV123_10fps_bike1", benchmark="UAV123@10fps", **_CPCF,
         frames="CPCF-tracker1/seq/bike1", first=1, last=1029, expected=1029,
         gt=["CPCF-tracker1/seq/bike1.txt"]),
    dict(name="UAV123_10fps_person12_2", benchmark="UAV123@10fps", **_CPCF,
         frames="CPCF-tracker1/seq/person12", first=201, last=541, expected=341,
         gt=[(*_TOOLKIT, _TOOLKIT_ANNO + "person12_2.txt")]),
    dict(name="UAV123_10fps_group2_1", benchmark="UAV123@10fps", **_TSD,
         frames="UAV123_10fps/data_seq/group2", first=1, last=303, expected=303,
         gt=[(*_TOOLKIT, _TOOLKIT_ANNO + "group2_1.txt")]),
    dict(name="UAV123_10fps_group2_2", benchmark="UAV123@10fps", **_TSD,
         frames="UAV123_10fps/data_seq/group2", first=303, last=591, expected=289,
         gt=["UAV123_10fps/anno/group2_2.txt"]),
    dict(name="UAV123_10fps_group2_3", benchmark="UAV123@10fps", **_TSD,
         frames="UAV123_10fps/data_seq/group2", first=591, last=895, expected=305,
         gt=[(*_TOOLKIT, _TOOLKIT_ANNO + "group2_3.txt")]),
]
