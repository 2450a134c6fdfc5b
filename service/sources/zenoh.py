"""Zenoh frame source: frames the sim publishes on `<prefix>/camera/frame` (zenoh_wire format).

The subscriber callback only stores the newest payload (one slot, older ones dropped and counted);
decoding happens on the capture thread, so a slow tracker never queues frames in Zenoh.
"""
from __future__ import annotations

import math
import time

from service.sources.base import CorruptFrame, Frame, LatestSlot, SourceError
from service.sources.zenoh_wire import decode_frame


def frame_key(prefix: str) -> str:
    """Key expression frames are published on."""
    return f"{prefix}/camera/frame"


class ZenohReader:
    """Subscribes on an open zenoh.Session (owned by the caller)."""

    def __init__(self, session: object, prefix: str) -> None:
        self.session = session
        self.key = frame_key(prefix)
        self.name = f"zenoh:{self.key}"
        self._slot: LatestSlot[bytes] = LatestSlot()
        self._subscriber: object | None = None

    @property
    def dropped(self) -> int:
        return self._slot.dropped

    def open(self) -> None:
        if self._subscriber is not None:
            return
        try:
            self._subscriber = self.session.declare_subscriber(  # type: ignore[attr-defined]
                self.key, lambda sample: self._slot.put(sample.payload.to_bytes()))
        except Exception as exc:  # zenoh raises its own ZError
            raise SourceError(f"cannot subscribe to {self.key}: {exc}") from exc

    def frame_interval_s(self) -> float | None:
        return None

    def read(self, timeout_s: float) -> Frame | None:
        payload = self._slot.take(timeout_s)
        if payload is None:
            return None
        try:
            wire = decode_frame(payload)
        except ValueError as exc:
            raise CorruptFrame(str(exc)) from exc
        if not math.isfinite(wire.timestamp):  # the controllers integrate over capture-time intervals
            raise CorruptFrame(f"frame {wire.frame_id}: capture timestamp {wire.timestamp} is not finite")
        return Frame(wire.image, wire.frame_id, wire.timestamp, time.monotonic())

    def close(self) -> None:
        if self._subscriber is not None:
            try:
                self._subscriber.undeclare()  # type: ignore[attr-defined]
            except Exception:  # noqa: BLE001 - the session may already be closed at shutdown
                pass
            self._subscriber = None
