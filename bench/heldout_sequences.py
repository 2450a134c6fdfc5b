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
names; UAV123 sub-sequences share their boundary frame). All UAV123@10fps; none has absent frames.
group1_1 is another part of the flight whose group1_3 is in *more* (same people, other frames).
"""

TITLE = "held-out (never used for a decision)"

_ARCF = dict(repo="vision4robotics/ARCF-tracker", commit="35ba2cc88024edfa76079048c61fc8cc1ea67e4b")
_OMFL = dict(repo="vision4robotics/OMFL-Tracker", commit="ebaf93201a990c46b9bdddd1f8953676c0298ec0")

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
]
