"""Service threads carry their names into the OS (/proc/PID/task/TID/comm), where `top -H` and the service
benchmark's per-thread report (bench.service) see them."""
from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from service.sources.base import CaptureWorker, EndOfStream, Frame, LatestSlot
from service.threads import OS_NAME_MAX_BYTES, os_thread_name, service_thread
from service.video.latest_frame_worker import LatestFrameWorker

WAIT_S = 10.0
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread names in /proc are Linux's")


def own_os_name() -> str:
    """The kernel name of the calling thread."""
    return Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().rstrip("\n")


def test_os_names_are_cut_to_15_bytes_never_inside_a_character() -> None:
    assert os_thread_name("tracking-loop") == b"tracking-loop"
    assert os_thread_name("capture-file:UAVDT_S1301_640x480.avi") == b"capture-file:UA"
    assert len(os_thread_name("x" * 40)) == OS_NAME_MAX_BYTES
    assert os_thread_name("video-prévisualisation") == "video-prévisua".encode()  # é is two bytes
    assert os_thread_name("abcdefghijklmn\u00e9") == b"abcdefghijklmn"  # the é would straddle byte 15


@linux_only
def test_a_service_thread_carries_its_name_into_the_os() -> None:
    seen: list[str] = []
    thread = service_thread(lambda: seen.append(own_os_name()), "mavlink-rx")
    thread.start()
    thread.join(WAIT_S)
    assert thread.name == "mavlink-rx" and thread.daemon
    assert seen == ["mavlink-rx"]
    assert own_os_name() != "mavlink-rx"  # the calling thread keeps its own


@linux_only
def test_the_video_worker_and_the_capture_thread_are_named_in_the_os() -> None:
    seen: dict[str, str] = {}
    encoded = threading.Event()

    def sink(frame: Frame) -> None:
        seen["video"] = own_os_name()
        encoded.set()

    worker = LatestFrameWorker("preview", sink, max_fps=30.0)
    worker.start()
    worker.offer(Frame(np.zeros((4, 4, 3), np.uint8), 0, 1000.0, 0.0))
    assert encoded.wait(WAIT_S)
    worker.stop(WAIT_S)

    class OneFrameReader:
        name = "file:clip.avi"

        def open(self) -> None:
            pass

        def frame_interval_s(self) -> None:
            return None

        def read(self, timeout_s: float) -> Frame:
            seen["capture"] = own_os_name()
            raise EndOfStream("one read is enough")

        def close(self) -> None:
            pass

    capture = CaptureWorker(OneFrameReader(), LatestSlot(), 0.1, 0.1)
    capture.start()
    assert capture.health.wait_for(lambda health: health.state == "ended", WAIT_S)
    capture.stop(WAIT_S)
    assert seen == {"video": "video-preview", "capture": "capture-file:cl"}
