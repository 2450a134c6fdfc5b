"""Hands the tracked frames to one slow consumer (an encoder) without ever delaying the tracking loop.

`offer(frame)` runs on the tracking thread: a rate check and a one-slot mailbox put. The consumer
(`sink`) runs on the worker's own thread and takes the newest frame; frames replaced before it took
them are counted as `dropped`, frames thinned out by the configured rate as `rate_skipped`.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

from service.sources.base import Frame, LatestSlot
from service.threads import service_thread

log = logging.getLogger("service.video")
PACE_SLACK = 0.25  # a frame up to this fraction of a period early still counts as due (camera jitter)


@dataclass(frozen=True)
class Pace:
    """Rate thinning state: the time (s, service monotonic clock) the next frame is due; None = first."""

    next_due_s: float | None = None


def pace_step(pace: Pace, now_s: float, period_s: float) -> tuple[bool, Pace]:
    """(take this frame?, new state) for frames arriving at now_s, at most one per period_s on average.

    A frame up to PACE_SLACK * period early is taken (so a 30 fps camera thinned to 30 fps keeps every
    frame despite jitter); after a gap longer than one period the schedule restarts from now_s.
    """
    due = pace.next_due_s
    if due is not None and now_s < due - PACE_SLACK * period_s:
        return False, pace
    if due is None or now_s - due >= period_s:
        return True, Pace(now_s + period_s)
    return True, Pace(due + period_s)


def fit_size(size: tuple[int, int], max_size: tuple[int, int], even: bool = False) -> tuple[int, int]:
    """(width, height) px of a frame of `size` scaled down to fit inside `max_size`, aspect kept, never
    enlarged; `even` rounds both down to even numbers (H.264 4:2:0 needs them), at least 2 px."""
    width, height = size
    scale = min(1.0, max_size[0] / width, max_size[1] / height)
    out_w, out_h = max(1, round(width * scale)), max(1, round(height * scale))
    if even:
        out_w, out_h = max(2, out_w - out_w % 2), max(2, out_h - out_h % 2)
    return out_w, out_h


class LatestFrameWorker:
    """Runs `sink(frame)` on its own thread for the newest offered frame, at most `max_fps` per second.

    A sink exception is counted (`errors`) and logged (the first of a run at WARNING), and the worker
    carries on with the next frame; `close()` is called on the worker thread when it stops.
    """

    def __init__(self, name: str, sink: Callable[[Frame], None], max_fps: float,
                 close: Callable[[], None] = lambda: None) -> None:
        if max_fps <= 0:
            raise ValueError(f"max_fps must be > 0, got {max_fps}")
        self.name = name
        self._sink = sink
        self._close = close
        self._period_s = 1.0 / max_fps
        self._pace = Pace()
        self._slot: LatestSlot[Frame] = LatestSlot()
        self._lock = threading.Lock()
        self._done = threading.Condition()  # notified after each sink call (success or failure)
        self._stop = threading.Event()
        self._thread = service_thread(self._run, f"video-{name}")
        self.offered = 0
        self.rate_skipped = 0
        self.sent = 0
        self.errors = 0
        self.cpu_s = 0.0  # CPU time (s) of the worker's thread in the sink: the encoder's own cost
        self.last_sent_frame_id: int | None = None

    @property
    def dropped(self) -> int:
        """Frames replaced in the mailbox before the sink took them (the sink was too slow)."""
        return self._slot.dropped

    def counters(self) -> dict[str, int]:
        return {"offered": self.offered, "rate_skipped": self.rate_skipped, "dropped": self.dropped,
                "sent": self.sent, "errors": self.errors, "cpu_ms": round(self.cpu_s * 1e3)}

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until predicate() holds, re-checked after each sink call; False on timeout."""
        with self._done:
            return self._done.wait_for(predicate, timeout=timeout_s)

    def offer(self, frame: Frame) -> None:
        """Tracking thread: hand `frame` over if it is due at the configured rate; never waits for the sink."""
        with self._lock:
            self.offered += 1
            due, self._pace = pace_step(self._pace, frame.read_monotonic_s, self._period_s)
            if not due:
                self.rate_skipped += 1
                return
        self._slot.put(frame)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Stop after the frame in hand (a sink stuck longer than timeout_s is abandoned: daemon thread)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        failing = False
        try:
            while not self._stop.is_set():
                frame = self._slot.take(timeout_s=0.1)
                if frame is None:
                    continue
                started = time.thread_time()
                try:
                    self._sink(frame)
                except Exception as exc:  # noqa: BLE001 - a failed encode must not stop the output
                    log.log(logging.DEBUG if failing else logging.WARNING,
                            'event=video_output_failed output=%s frame_id=%d error="%s: %s"',
                            self.name, frame.frame_id, type(exc).__name__, exc)
                    failing = True
                    self.cpu_s += time.thread_time() - started
                    with self._done:
                        self.errors += 1
                        self._done.notify_all()
                    continue
                if failing:
                    log.info("event=video_output_recovered output=%s errors=%d", self.name, self.errors)
                    failing = False
                self.cpu_s += time.thread_time() - started
                with self._done:
                    self.sent += 1
                    self.last_sent_frame_id = frame.frame_id
                    self._done.notify_all()
        finally:
            try:
                self._close()
            except Exception:  # noqa: BLE001 - closing at shutdown
                log.exception("event=video_output_close_failed output=%s", self.name)


class WorkerOutput:
    """A video output whose encoding runs on its LatestFrameWorker (`self.worker`): offer / start / stop."""

    worker: LatestFrameWorker

    def offer(self, frame: Frame) -> None:
        """Tracking thread: hand the frame over (never waits for the encoder)."""
        self.worker.offer(frame)

    def start(self) -> None:
        self.worker.start()

    def stop(self, timeout_s: float = 0.5) -> None:
        self.worker.stop(timeout_s)
