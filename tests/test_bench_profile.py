"""bench.profile's parsing and grouping of callgrind dumps, and its stage markers (no callgrind run)."""
from __future__ import annotations

from collections import Counter

import pytest

from bench.profile import (Dump, StageMarks, by_function, by_library, collect, dumps_from_marks, marker_cost,
                           parse_dumps, report, row_of,
                           summary)

# Two dumps of one run: names are compressed per run, so the second file uses ids the first defined.
FIRST = """# callgrind format
version: 1
part: 1
desc: Trigger: Client Request: seq|jsar|1|locate/features

positions: line
events: Ir
summary: 1100

ob=(1) /opt/lib/libpython3.11.so.1.0
fl=(1) ceval.c
fn=(1) _PyEval_EvalFrameDefault
10 300
+2 200
cob=(2) /opt/site-packages/numpy/_core/_multiarray_umath.cpython-311-x86_64-linux-gnu.so
cfi=(2) loops.c
cfn=(2) CFLOAT_multiply_X86_V3
calls=3 40
* 999999
* 100

ob=(2)
fl=(2)
fn=(2)
40 400
fn=(3) ufunc_generic_fastcall
50 50
fi=(3) inline.h
51 50

totals: 1100
"""
SECOND = """# callgrind format
version: 1
part: 2
desc: Trigger: Client Request: seq|jsar|1|

positions: line
events: Ir
summary: 70

ob=(1)
fn=(1)
10 7
ob=(3) /lib/x86_64-linux-gnu/libc.so.6
fn=(4) __memcpy_avx_unaligned_erms
0 60
fn=(5) malloc
0 3

totals: 70
"""


def test_parse_dumps_keeps_self_costs_and_run_wide_names():
    first, second = parse_dumps([FIRST, SECOND])
    python = "/opt/lib/libpython3.11.so.1.0"
    numpy = "/opt/site-packages/numpy/_core/_multiarray_umath.cpython-311-x86_64-linux-gnu.so"
    assert first.label == "seq|jsar|1|locate/features" and first.summary == 1100
    # The line after calls= is the call's inclusive cost (999999): the caller's own costs exclude it.
    assert first.costs == Counter({(python, "_PyEval_EvalFrameDefault"): 600,
                                   (numpy, "CFLOAT_multiply_X86_V3"): 400,
                                   (numpy, "ufunc_generic_fastcall"): 100})
    assert sum(first.costs.values()) == first.total
    assert second.costs[(python, "_PyEval_EvalFrameDefault")] == 7  # "(1)" resolved from the first file
    assert second.label == "seq|jsar|1|" and sum(second.costs.values()) == second.total == 70


def test_libraries_split_numpy_and_libc_by_function():
    grouped = by_library(Counter(parse_dumps([FIRST, SECOND])[0].costs + parse_dumps([FIRST, SECOND])[1].costs))
    assert grouped == Counter({"interpreter (libpython)": 607, "numpy: element loops, casts": 400,
                               "numpy: per-call work": 100, "libc: memcpy, memset": 60,
                               "libc: malloc, free, rest": 3})
    assert by_library(Counter({("/x/_kernels.cpython-311-x86_64-linux-gnu.so", "fhog_one"): 5,
                               ("/x/cv2.abi3.so", "0x1"): 2, ("/x/ld-linux-x86-64.so.2", "f"): 1})) == Counter(
        {"jsar kernels (_kernels)": 5, "OpenCV (cv2)": 2, "other": 1})
    assert by_function(Counter({("/a/libc.so.6", "malloc"): 2, ("/b/libc.so.6", "malloc"): 3})) == Counter(
        {("malloc", "libc.so.6"): 5})


def test_row_is_the_first_whose_stages_appear_in_order():
    rows = (("translation fHOG", ("locate", "fHOG")), ("size crops", ("size sample", "crop")),
            ("translation", ("locate",)), ("size crops", ("size filter", "crop")))
    assert row_of("locate/features/fHOG", rows) == "translation fHOG"
    assert row_of("locate/features", rows) == "translation"
    assert row_of("commit/size filter/size sample/crop", rows) == "size crops"
    assert row_of("crop/size sample", rows) == "rest"  # the stages in the other order
    assert row_of("commit", rows) == "rest" and row_of("", rows) == "rest"


def test_collect_sums_counters_per_kind_and_stage_and_skips_other_dumps():
    dumps = [Dump("calibration|plain|0|", summary=1000), Dump("calibration|marked|0|noop", summary=3000),
             Dump("uncounted", summary=10**9),
             Dump("s|jsar|1|", Counter({("libc.so.6", "malloc"): 12}), summary=10),
             Dump("s|jsar|1|locate/features", Counter({("libc.so.6", "malloc"): 20}), summary=20),
             Dump("s|jsar|1|", summary=5), Dump("s|jsar|2|", summary=40), Dump("s|csrt|1|", summary=7)]
    profiles = collect(dumps)
    assert set(profiles) == {("s", "jsar"), ("s", "csrt")}
    jsar = profiles[("s", "jsar")]
    assert jsar.stages == Counter({"": 55, "locate/features": 20}) and jsar.frames == Counter({"1": 35, "2": 40})
    assert jsar.costs == Counter({("libc.so.6", "malloc"): 32}) and jsar.segments == 4
    assert marker_cost(dumps) == 20.0  # (3000 - 1000) instructions over 100 calls
    result = summary(profiles, 20.0)["sequences"]["s"]["jsar"]
    assert result["total"] == pytest.approx(37.5e-6) and result["frame_totals"] == pytest.approx([35e-6, 40e-6])
    assert result["stage_calls_per_frame"] == 0.5  # 4 segments = 2 frame ends + 2 dumps of one stage call
    assert result["stages"] == pytest.approx({"rest": 27.5e-6, "translation: gray, feature stack": 10e-6})


def test_stage_marks_label_each_segment_with_the_open_stages():
    labels: list[str] = []
    marks = StageMarks(labels.append)

    def inner() -> int:
        return 3

    def failing() -> None:
        raise ValueError("boom")

    marked_inner = marks.wrap(inner, "inner")
    marked_outer = marks.wrap(lambda: marked_inner() + 1, "outer")
    marked_failing = marks.wrap(failing, "failing")
    assert marked_outer() == 4 and labels == []  # outside a counted frame: no dumps
    marks.frame_call("s|jsar|1", marked_outer)
    assert labels == ["s|jsar|1|", "s|jsar|1|outer", "s|jsar|1|outer/inner", "s|jsar|1|outer", "s|jsar|1|"]
    labels.clear()
    with pytest.raises(ValueError):
        marks.frame_call("s|jsar|2", marked_failing)
    assert labels == ["s|jsar|2|", "s|jsar|2|failing"] and marks.frame == "" and marks.stack == []


def test_marks_under_qemu_give_one_segment_per_mark_and_a_stage_report(capsys):
    """--arm64-rootfs: the worker prints "DUMP i label" at mark i, the plugin the count there; the segment labelled
    i is what ran since mark i - 1. The report then has stage tables and says it has no per-function costs."""
    out = "\n".join(["noise", "DUMP 0 uncounted", "DUMP 1 s|jsar|1|", "DUMP 2 s|jsar|1|locate/features",
                     "DUMP 3 s|jsar|1|", "DUMP 4 uncounted", "DUMP 5 s|jsar|2|"])
    counts = {0: 1000, 1: 1100, 2: 1400, 3: 1450, 4: 9000, 5: 9070}
    dumps = dumps_from_marks(out, counts)
    assert [(d.label, d.summary) for d in dumps] == [("s|jsar|1|", 100), ("s|jsar|1|locate/features", 300),
                                                    ("s|jsar|1|", 50), ("uncounted", 7550), ("s|jsar|2|", 70)]
    profile = collect(dumps)[("s", "jsar")]
    assert profile.frames == Counter({"1": 450, "2": 70}) and not profile.costs
    report(summary(collect(dumps), 0.0))
    printed = capsys.readouterr().out
    assert "no per-function costs" in printed and "(b) by stage, tracked frames" in printed
    assert "(c) jsar" not in printed
