"""Held-out UAV sequences: a manifest for the shared data tool, never used for a tracker decision.

Issue 15's fourteen rounds of decisions were all measured on *more* (12 sequences), so *more* is no
longer fresh. These sequences were listed after the last of those decisions and are scored once per
tracker change, to see whether what was measured on *more* holds on video nobody tuned on. Do not
tune on them; when a decision needs more data, add sequences to a new held-out list instead.

Make them (frames and ground truth stay outside the repository):

    python3 ../shared/tools/get_more_data.py --list-repos --manifest bench/heldout_sequences.py
    # fetch each printed snapshot with the search tool's `fetch`, then
    python3 ../shared/tools/get_more_data.py MIRROR_DIR HELDOUT_DIR --manifest bench/heldout_sequences.py

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

def _uav123(sub: str, source: dict, frames: str, first: int, last: int, gt: str | tuple[str, str, str]) -> dict:
    """One UAV123@10fps record: frames first..last (1-based, inclusive) of folder `frames` in `source`'s
    snapshot; `gt` a path there, or (repo, commit, path) in another snapshot."""
    return dict(name=f"UAV123_10fps_{sub}", benchmark="UAV123@10fps", **source, frames=frames,
                first=first, last=last, expected=last - first + 1, gt=[gt])


MANIFEST = [
    _uav123("boat1", _ARCF, "seq/boat1", 1, 301, "seq/boat1.txt"),
    _uav123("building4", _ARCF, "seq/building4", 1, 263, "seq/building4.txt"),
    _uav123("person12_1", _ARCF, "seq/person12", 1, 201, "seq/person12_1.txt"),
    _uav123("truck4_1", _ARCF, "seq/truck4", 1, 193, "seq/truck4_1.txt"),
    _uav123("truck4_2", _ARCF, "seq/truck4", 193, 421, "seq/truck4_2.txt"),
    _uav123("building5", _OMFL, "UAV123_10fps/data_seq/building5", 1, 161, "UAV123_10fps/anno/building5.txt"),
    _uav123("group1_1", _OMFL, "UAV123_10fps/data_seq/group1", 1, 445, "UAV123_10fps/anno/group1_1.txt"),
    _uav123("boat4", _RESL, "UAV123_10fps/data_seq/boat4", 1, 185, "UAV123_10fps/anno/boat4.txt"),
    _uav123("car14", _BEVT, "seq/car14", 1, 443, "seq/car14.txt"),
    _uav123("wakeboard4", _BEVT, "seq/wakeboard4", 1, 233, "seq/wakeboard4.txt"),
    _uav123("person11", _BICF, "sequences/person11/img", 1, 241, "sequences/person11/groundtruth_rect.txt"),
    _uav123("bike1", _CPCF, "CPCF-tracker1/seq/bike1", 1, 1029, "CPCF-tracker1/seq/bike1.txt"),
    _uav123("person12_2", _CPCF, "CPCF-tracker1/seq/person12", 201, 541, (*_TOOLKIT, _TOOLKIT_ANNO + "person12_2.txt")),
    _uav123("group2_1", _TSD, "UAV123_10fps/data_seq/group2", 1, 303, (*_TOOLKIT, _TOOLKIT_ANNO + "group2_1.txt")),
    _uav123("group2_2", _TSD, "UAV123_10fps/data_seq/group2", 303, 591, "UAV123_10fps/anno/group2_2.txt"),
    _uav123("group2_3", _TSD, "UAV123_10fps/data_seq/group2", 591, 895, (*_TOOLKIT, _TOOLKIT_ANNO + "group2_3.txt")),
]
