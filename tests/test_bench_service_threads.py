"""The service benchmark's per-thread report (bench.service --threads-report): /proc stat lines parsed, threads
grouped by their OS names, CPU ms per frame between two samples."""
from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from bench.service import (THREAD_GROUPS, callgrind_dump_totals, cpu_ms_by_group, instructions_report, parse_stat,
                           per_camera_frame, per_frame, thread_group, thread_times, vgdb_threads)

PID = 4000


def stat_line(tid: int, comm: str, utime: int, stime: int) -> str:
    """A /proc/PID/task/TID/stat line as the kernel writes it (proc(5)): utime and stime are fields 14 and 15."""
    return (f"{tid} ({comm}) S 1 {PID} {PID} 0 -1 4194368 1208 0 3 0 {utime} {stime} 0 0 39 19 23 0 "
            "5126120 1437609984 27418 18446744073709551615 1 1 0 0 0 0 0 4096 17638 0 0 0 -1 0 0 0 0 0 0 0 0 0 0 "
            "0 0 0\n")


def test_a_stat_line_gives_its_comm_and_cpu_ticks_even_with_spaces_and_parentheses_in_the_comm() -> None:
    assert parse_stat(stat_line(4001, "tracking-loop", 812, 31)) == ("tracking-loop", 843)
    assert parse_stat(stat_line(4002, "Watchdog Confir", 5, 2)) == ("Watchdog Confir", 7)
    assert parse_stat(stat_line(4003, "a) S 1 (b", 100, 20)) == ("a) S 1 (b", 120)  # a comm that looks like fields
    assert parse_stat(stat_line(4004, ") )", 0, 9)) == (") )", 9)


def test_threads_are_grouped_by_their_os_names() -> None:
    assert thread_group("python", PID, PID) == "main"
    assert thread_group("tracking-loop", PID, PID) == "main"  # the first thread is main whatever its name
    assert thread_group("tracking-loop", 4001, PID) == "tracking-loop"
    assert thread_group("capture-file:UA", 4002, PID) == "capture"
    assert thread_group("capture-v4l2:/d", 4002, PID) == "capture"
    for name in ("verifier", "mavlink-rx", "mavlink-tx", "video-preview", "video-stream"):
        assert thread_group(name, 4003, PID) == name
    for zenoh in ("app-0", "acc-1", "net-0", "rx-12", "tx-0", "Watchdog Confir", "Watchdog Valida"):
        assert thread_group(zenoh, 4004, PID) == "zenoh runtime"
    for native in ("python", "app-x", "rx", "tx-", "Watchdog", "ThreadPoolForeg", "video-previews"):
        assert thread_group(native, 4005, PID) == "other native"


def test_cpu_ms_by_group_counts_each_threads_ticks_between_the_samples() -> None:
    start = {PID: ("python", 500), 4001: ("tracking-loop", 1000), 4002: ("capture-file:UA", 200),
             4003: ("rx-0", 10), 4004: ("tx-0", 10), 4009: ("gone-before-end", 50)}
    end = {PID: ("python", 500), 4001: ("tracking-loop", 1300), 4002: ("capture-file:UA", 230),
           4003: ("rx-0", 16), 4004: ("tx-0", 13), 4010: ("Watchdog Confir", 1), 4011: ("python", 3)}
    # 100 ticks a second: 300 ticks = 3 s
    got = cpu_ms_by_group(start, end, PID, ticks_per_s=100.0, process_ticks=300 + 30 + 10 + 3 + 20)
    assert set(got) == set(THREAD_GROUPS)
    assert got["tracking-loop"] == pytest.approx(3000.0)
    assert got["capture"] == pytest.approx(300.0)
    assert got["zenoh runtime"] == pytest.approx((6 + 3 + 1) * 10)  # a thread born in between counts from 0
    assert got["other native"] == pytest.approx(3 * 10)
    assert got["ended threads"] == pytest.approx(20 * 10)  # the process's ticks the live threads do not explain
    assert got["main"] == 0.0 and got["video-stream"] == 0.0
    assert cpu_ms_by_group(start, end, PID, ticks_per_s=100.0)["ended threads"] == 0.0  # without the process's
    assert per_frame({"tracking-loop": 3000.0, "capture": 300.0}, 150) == {"tracking-loop": 20.0, "capture": 2.0}
    with pytest.raises(ValueError):
        per_frame(got, 0)


def test_per_camera_frame_divides_each_thread_by_its_own_frames_and_the_rest_by_time() -> None:
    cpu_ms = {"tracking-loop": 3000.0, "capture": 300.0, "video-preview": 100.0, "video-stream": 0.0,
              "mavlink-tx": 15.0, "zenoh runtime": 30.0}
    counts = {"loop": 150, "source": 300, "preview_sent": 100, "stream_sent": 0}  # a slow loop dropped half the frames
    got = per_camera_frame(cpu_ms, counts, wall_s=10.0, fps=30.0, shares={"video-preview": 0.5})
    assert got["tracking-loop"] == pytest.approx(20.0)  # per frame tracked
    assert got["capture"] == pytest.approx(1.0)  # per frame read
    assert got["video-preview"] == pytest.approx(0.5)  # 1 ms per preview, every second camera frame
    assert got["video-stream"] == 0.0  # nothing sent: off
    assert got["zenoh runtime"] == pytest.approx(0.2)  # per frame tracked: the telemetry
    assert got["mavlink-tx"] == pytest.approx(1.5 / 30)  # per second / fps: heartbeats and status on timers


def test_thread_times_reads_this_process_threads_by_their_os_names() -> None:
    from service.threads import service_thread

    inside, release = threading.Event(), threading.Event()

    def busy() -> None:
        inside.set()
        release.wait(10.0)

    thread = service_thread(busy, "video-stream")
    thread.start()
    try:
        assert inside.wait(10.0)
        sample = thread_times(os.getpid())
    finally:
        release.set()
        thread.join(10.0)
    assert sample[os.getpid()][0] == parse_stat(Path(f"/proc/{os.getpid()}/stat").read_text())[0]
    assert sample[thread.native_id][0] == "video-stream"
    assert all(ticks >= 0 for _, ticks in sample.values())


def test_valgrind_threads_are_mapped_to_os_threads_from_vgdbs_scheduler_report() -> None:
    report = """sending command v.info scheduler to pid 24234

sched status:
  running_tid=2

Thread 1: status = VgTs_WaitSys syscall 202 (lwpid 24234)
==24234==    at 0x4E87F16: __futex_abstimed_wait_common (futex-internal.c:57)
Thread 2: status = VgTs_Runnable (lwpid 24258)
==24234==    by 0x4E92115: __new_sem_wait_slow64 (sem_waitcommon.c:183)
Thread 12: status = VgTs_WaitSys syscall 7 (lwpid 24301)
client stack range: [0x1FFEFEE000 0x1FFF000FFF] client SP: 0x1FFF000000
"""
    assert vgdb_threads(report) == {1: 24234, 2: 24258, 12: 24301}
    assert vgdb_threads("") == {}


def test_a_callgrind_dump_gives_its_thread_and_instruction_count() -> None:
    dump = ("# callgrind format\nversion: 1\ncreator: callgrind-3.19.0\npid: 23695\ncmd:  python -m service\n"
            "part: 1\nthread: 7\n\ndesc: I1 cache: \npositions: line\nevents: Ir\nsummary: 3687091155\n\n"
            "ob=(1)\nfn=(1) main\n0 12\ntotals: 3687091155\n")
    assert callgrind_dump_totals(dump) == (7, 3687091155)
    with pytest.raises(ValueError):
        callgrind_dump_totals("# callgrind format\nevents: Ir\nsummary: 12\n")  # the whole process, not a thread


def test_instructions_are_grouped_like_cpu_time_and_unmapped_threads_count_as_ended() -> None:
    threads = {PID: ("callgrind-amd64", 0), 4001: ("tracking-loop", 0), 4002: ("capture-file:UA", 0)}
    counts = {PID: 1_000, 4001: 300_000_000, 4002: 20_000_000, -1: 5_000}
    got = instructions_report(counts, threads, PID, {"loop": 10, "source": 20, "preview_sent": 0, "stream_sent": 0},
                              wall_s=50.0, shares={})
    assert got["thread_instructions"]["main"] == 1_000 and got["thread_instructions"]["ended threads"] == 5_000
    per_frame_counts = got["thread_instructions_per_camera_frame"]
    assert per_frame_counts["tracking-loop"] == pytest.approx(30e6)
    assert per_frame_counts["capture"] == pytest.approx(1e6)
    assert per_frame_counts["main"] == pytest.approx(1_000 / 50 / 30)
