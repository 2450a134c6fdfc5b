"""Frame sources: the reader protocol, the latest-frame-wins mailbox and the capture worker.

A reader (v4l2, file, zenoh) only knows how to open, read one frame and close. The capture worker
runs it on its own thread, pushes each frame into a one-slot mailbox (a frame not yet taken is
replaced and counted as dropped, never queued), reports health, and on failure closes the reader and
retries with exponential backoff. End of stream (a file without `loop`) is terminal.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Generic, Literal, Protocol, TypeVar

import numpy as np

from service.threads import service_thread

log = logging.getLogger("service.source")

T = TypeVar("T")
HealthState = Literal["starting", "ok", "error", "ended"]


class SourceError(Exception):
    """The source failed (device absent or unplugged, file unreadable); the worker retries."""


class CorruptFrame(Exception):
    """One frame could not be decoded; it is counted and skipped."""


class EndOfStream(Exception):
    """The source has no more frames (end of a file played without `loop`)."""


@dataclass(frozen=True)
class Frame:
    """One captured frame: HxWx3 BGR or HxW grey uint8 image.

    frame_id: increasing per source; capture_time_s: the source's timestamp (seconds, wall clock: read
    time for v4l2 / file, the publisher's header timestamp for zenoh), the clock the controllers
    integrate over; read_monotonic_s: time.monotonic() when the worker received it, the start of the
    service's latency measurements.
    """

    image: np.ndarray
    frame_id: int
    capture_time_s: float
    read_monotonic_s: float


class FrameReader(Protocol):
    """An I/O adapter producing frames; the worker calls open, read repeatedly, close."""

    name: str

    def open(self) -> None:
        """Open the device / file / subscription; SourceError on failure."""

    def read(self, timeout_s: float) -> Frame | None:
        """Next frame, or None if none arrived within timeout_s; CorruptFrame, EndOfStream, SourceError."""

    def close(self) -> None:
        """Release the device; safe to call twice."""

    def frame_interval_s(self) -> float | None:
        """Pacing interval the worker keeps between frames (a file at its frame rate), None = unpaced."""


class LatestSlot(Generic[T]):
    """A one-slot mailbox: put replaces an untaken item and counts it as dropped; take waits."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: T | None = None
        self.dropped = 0
        self.put_count = 0

    def put(self, item: T) -> None:
        """Store `item`, replacing (and counting as dropped) one not yet taken."""
        with self._cond:
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self.put_count += 1
            self._cond.notify_all()

    def take(self, timeout_s: float) -> T | None:
        """The newest item, waiting up to timeout_s; None on timeout."""
        with self._cond:
            if self._item is None:
                self._cond.wait_for(lambda: self._item is not None, timeout=timeout_s)
            item, self._item = self._item, None
            return item


@dataclass
class SourceHealth:
    """Thread-safe health and counters of a source, read by status reports."""

    state: HealthState = "starting"
    reason: str = ""
    frames: int = 0
    corrupt: int = 0
    failures: int = 0
    last_frame_size: tuple[int, int] | None = None  # (width, height) pixels
    _lock: threading.Condition = field(default_factory=threading.Condition, repr=False)

    def set(self, state: HealthState, reason: str = "") -> None:
        with self._lock:
            changed = (state, reason) != (self.state, self.reason)
            self.state, self.reason = state, reason
            self._lock.notify_all()
        if changed:
            level = logging.WARNING if state in ("error", "ended") else logging.INFO
            log.log(level, "event=source_state state=%s reason=%s", state, _quote(reason))

    def wait_for(self, predicate: "Callable[[SourceHealth], bool]", timeout_s: float) -> bool:
        """Wait until predicate(self) holds (checked on every state change); False on timeout."""
        with self._lock:
            return self._lock.wait_for(lambda: predicate(self), timeout=timeout_s)

    def snapshot(self) -> dict[str, object]:
        with self._lock:
            return {"state": self.state, "reason": self.reason, "frames": self.frames,
                    "corrupt": self.corrupt, "failures": self.failures,
                    "frame_size": list(self.last_frame_size) if self.last_frame_size else None}


JPEG_EOI = b"\xff\xd9"  # JPEG's end-of-image marker


def is_complete_jpeg(data: bytes | memoryview) -> bool:
    """Whether a JPEG stream ends with its end-of-image marker (trailing zero padding allowed). OpenCV's
    imread decodes a truncated file into a full-size image whose missing part is grey, with only a warning
    on stderr: without this check a half-written frame would be tracked as if it were the scene."""
    return bytes(data[-64:]).rstrip(b"\x00").endswith(JPEG_EOI)


def backoff_delays(initial_s: float, max_s: float):
    """Infinite generator of retry delays: initial, doubled each time, capped at max_s (seconds)."""
    delay = initial_s
    while True:
        yield delay
        delay = min(delay * 2.0, max_s)


class CaptureWorker:
    """Runs a FrameReader on a thread, feeding `mailbox`; retries failures with backoff."""

    STALL_S = 2.0  # no frame for this long while open -> health "error" (stalled), until one arrives
    CORRUPT_RUN = 3  # this many undecodable frames in a row -> health "error", until a good one arrives

    def __init__(self, reader: FrameReader, mailbox: LatestSlot[Frame], retry_initial_s: float,
                 retry_max_s: float) -> None:
        self.reader = reader
        self.mailbox = mailbox
        self.health = SourceHealth()
        self._retry = (retry_initial_s, retry_max_s)
        self._stop = threading.Event()
        self._thread = service_thread(self._run, f"capture-{reader.name}")

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)

    @property
    def dropped(self) -> int:
        return self.mailbox.dropped + getattr(self.reader, "dropped", 0)

    def _run(self) -> None:
        delays = backoff_delays(*self._retry)
        while not self._stop.is_set():
            try:
                self.reader.open()
            except SourceError as exc:
                if not self._fail(str(exc), next(delays)):
                    return
                continue
            self.health.set("starting", "opened, waiting for the first frame")
            frames_before = self.health.frames
            failure: str | None = None
            try:
                self._pump()
            except EndOfStream as exc:
                self.reader.close()
                self.health.set("ended", str(exc) or "end of stream")
                return
            except SourceError as exc:
                failure = str(exc)
            except Exception as exc:  # noqa: BLE001 - a reader bug must not kill the service
                log.exception("event=source_crash reader=%s", self.reader.name)
                failure = f"{type(exc).__name__}: {exc}"
            self.reader.close()
            if failure is None:
                return  # stopped
            if self.health.frames > frames_before:
                delays = backoff_delays(*self._retry)  # it worked for a while: start the backoff afresh
            if not self._fail(failure, next(delays)):
                return

    def _fail(self, reason: str, delay_s: float) -> bool:
        """Record a failure, wait delay_s (or until stopped); False when stopping."""
        with self.health._lock:
            self.health.failures += 1
            self.health._lock.notify_all()
        self.health.set("error", f"{reason}; retry in {delay_s:.1f} s")
        return not self._stop.wait(delay_s)

    def _pump(self) -> None:
        """Read frames into the mailbox until stopped; raises what the reader raises (but CorruptFrame)."""
        interval = self.reader.frame_interval_s()
        next_due: float | None = None
        last_frame = time.monotonic()
        corrupt_run = 0  # undecodable frames since the last good one
        while not self._stop.is_set():
            if interval is not None and next_due is not None:
                # pace like a camera: one frame per interval; after a stall, restart the clock
                wait_s = next_due - time.monotonic()
                if wait_s > 0 and self._stop.wait(wait_s):
                    return
            try:
                frame = self.reader.read(timeout_s=0.2)
            except CorruptFrame as exc:
                if interval is not None:  # a corrupt frame takes its slot: a paced file keeps its frame rate
                    now = time.monotonic()
                    next_due = now + interval if next_due is None or next_due < now - interval else next_due + interval
                corrupt_run += 1
                with self.health._lock:
                    self.health.corrupt += 1
                    self.health._lock.notify_all()
                # the first of a run at WARNING, the rest at DEBUG: a stream of garbage must not flood the log
                log.log(logging.WARNING if corrupt_run == 1 else logging.DEBUG,
                        "event=corrupt_frame reader=%s run=%d reason=%s", self.reader.name, corrupt_run,
                        _quote(str(exc)))
                if corrupt_run == self.CORRUPT_RUN:
                    self.health.set("error", f"corrupt frames: {corrupt_run} in a row, no good frame since "
                                             f"(this one: {exc})")
                continue
            now = time.monotonic()
            if frame is not None and corrupt_run:
                log.info("event=corrupt_frames_ended reader=%s run=%d", self.reader.name, corrupt_run)
                corrupt_run = 0
            if frame is None:
                if now - last_frame > self.STALL_S:
                    self.health.set("error", f"no frame for {now - last_frame:.1f} s")
                continue
            if interval is not None:
                next_due = now + interval if next_due is None or next_due < now - interval else next_due + interval
            last_frame = now
            height, width = frame.image.shape[:2]
            with self.health._lock:
                self.health.frames += 1
                self.health.last_frame_size = (width, height)
                self.health._lock.notify_all()
            self.health.set("ok")
            self.mailbox.put(frame)


def _quote(text: str) -> str:
    """A log value with spaces quoted (key=value logs)."""
    return '"' + text.replace('"', "'") + '"' if (" " in text or not text) else text
