"""The service benchmark's per-thread report (bench.service --threads-report): /proc stat lines parsed, threads
grouped by their OS names, CPU ms per frame between two samples."""
from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from bench.service import THREAD_GROUPS, cpu_ms_per_frame_by_group, parse_stat, thread_group, thread_times

PID = 4000


def stat_line(tid: int, comm: str, utime: int, stime: int) -> str:
    """A /proc/PID/task/TID/stat line as the kernel writes it (proc(5)): utime and stime are fields 14 and 15."""
    return (f"{tid} ({comm}) S 1 {PID} {PID} 0 -1 4194368 1208 0 3 0 {utime} {stime} 0 0 39 19 23 0 "
            "5126120 1437609984 27418 18446744073709551615 1 1 0 0 0 0 0 4096 17638 0 0 0 -1 0 0 0 0 0 0 0 0 0 0 0 0 0\n")


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
    for name in ("mavlink-rx", "mavlink-tx", "video-preview", "video-stream"):
        assert thread_group(name, 4003, PID) == name
    for zenoh in ("app-0", "acc-1", "net-0", "rx-12", "tx-0", "Watchdog Confir", "Watchdog Valida"):
        assert thread_group(zenoh, 4004, PID) == "zenoh runtime"
    for native in ("python", "app-x", "rx", "tx-", "Watchdog", "ThreadPoolForeg", "video-previews"):
        assert thread_group(native, 4005, PID) == "other native"


def test_cpu_ms_per_frame_by_group_counts_each_threads_ticks_between_the_samples() -> None:
    start = {PID: ("python", 500), 4001: ("tracking-loop", 1000), 4002: ("capture-file:UA", 200),
             4003: ("rx-0", 10), 4004: ("tx-0", 10), 4009: ("gone-before-end", 50)}
    end = {PID: ("python", 500), 4001: ("tracking-loop", 1300), 4002: ("capture-file:UA", 230),
           4003: ("rx-0", 16), 4004: ("tx-0", 13), 4010: ("Watchdog Confir", 1), 4011: ("python", 3)}
    # 100 ticks a second, 150 frames: 300 ticks = 3 s = 3000 ms over 150 frames = 20 ms a frame
    got = cpu_ms_per_frame_by_group(start, end, PID, frames=150, ticks_per_s=100.0)
    assert set(got) == set(THREAD_GROUPS)
    assert got["tracking-loop"] == pytest.approx(20.0)
    assert got["capture"] == pytest.approx(2.0)
    assert got["zenoh runtime"] == pytest.approx((6 + 3 + 1) * 10 / 150)  # a thread born in between counts from 0
    assert got["other native"] == pytest.approx(3 * 10 / 150)
    assert got["main"] == 0.0 and got["video-stream"] == 0.0
    with pytest.raises(ValueError):
        cpu_ms_per_frame_by_group(start, end, PID, frames=0, ticks_per_s=100.0)


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
