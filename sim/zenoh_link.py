"""The sim's Zenoh side: publish camera frames, collect the daemon's per-frame telemetry, query status.

Keys (service <-> sim contract): frames on `<prefix>/camera/frame` (service/sources/zenoh_wire.py
format), telemetry JSON on `<prefix>/track`, status JSON from the queryable `<prefix>/status`.
"""
from __future__ import annotations

import collections
import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from service.config import ZenohConfig
from service.sources.zenoh_wire import encode_frame
from service.telemetry import zenoh_config


@dataclass(frozen=True)
class ZenohEndpoints:
    """Zenoh session settings; tests use mode peer, explicit tcp/127.0.0.1 endpoints, no multicast."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    prefix: str = "jsar"

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client"):
            raise ValueError(f"zenoh mode must be peer or client, got {self.mode!r}")
        if not self.prefix or self.prefix.startswith("/") or self.prefix.endswith("/"):
            raise ValueError(f"zenoh prefix must be a non-empty key without leading/trailing '/', got {self.prefix!r}")

    def to_zenoh(self) -> zenoh.Config:
        """The zenoh.Config these settings describe (built like the daemon's, service.telemetry)."""
        return zenoh_config(ZenohConfig(mode=self.mode, listen=self.listen, connect=self.connect,  # type: ignore[arg-type]
                                        multicast_scouting=self.multicast_scouting, prefix=self.prefix))


@dataclass
class TelemetryLog:
    """Telemetry samples by frame id (bounded), with a condition to wait on."""

    limit: int = 5000
    by_frame: "collections.OrderedDict[int, dict[str, Any]]" = field(default_factory=collections.OrderedDict)
    received: int = 0
    malformed: int = 0
    last: dict[str, Any] | None = None
    source_gone: bool = False  # the daemon has exited: nothing more will arrive (waits end at once)

    def __post_init__(self) -> None:
        self.cond = threading.Condition()

    def mark_source_gone(self) -> None:
        """The sender has ended: wake every wait_frame (they return what has arrived, None otherwise)."""
        with self.cond:
            self.source_gone = True
            self.cond.notify_all()

    def add(self, payload: bytes) -> None:
        """Store one JSON sample (malformed ones are counted, not raised: they come from another process)."""
        try:
            sample = json.loads(payload)
            frame_id = int(sample["frame_id"])
        except (ValueError, KeyError, TypeError):
            with self.cond:
                self.malformed += 1
            return
        with self.cond:
            self.by_frame[frame_id] = sample
            while len(self.by_frame) > self.limit:
                self.by_frame.popitem(last=False)
            self.received += 1
            self.last = sample
            self.cond.notify_all()

    def wait_frame(self, frame_id: int, timeout_s: float) -> dict[str, Any] | None:
        """The sample for frame_id (or a later frame: that one was skipped), None on timeout or when the
        source has gone (mark_source_gone) without sending it."""
        def arrived() -> bool:
            return self.last is not None and int(self.last["frame_id"]) >= frame_id

        with self.cond:
            self.cond.wait_for(lambda: arrived() or self.source_gone, timeout=timeout_s)
            if not arrived():
                return None
            return self.by_frame.get(frame_id, self.last)


class SimCamera:
    """Zenoh session of the sim: `publish(image, frame_id, timestamp)`, telemetry in `telemetry`."""

    def __init__(self, endpoints: ZenohEndpoints, pixel_format: bytes = b"BGR3") -> None:
        self.endpoints = endpoints
        self.pixel_format = pixel_format
        self.session = zenoh.open(endpoints.to_zenoh())
        self.telemetry = TelemetryLog()
        self.frame_key = f"{endpoints.prefix}/camera/frame"
        self.track_key = f"{endpoints.prefix}/track"
        self.status_key = f"{endpoints.prefix}/status"
        self._publisher = self.session.declare_publisher(self.frame_key)
        self._subscriber = self.session.declare_subscriber(
            self.track_key, lambda sample: self.telemetry.add(sample.payload.to_bytes()))

    def publish(self, image: np.ndarray, frame_id: int, timestamp: float | None = None) -> None:
        """Send one frame (capture time = now on the wall clock unless given)."""
        stamp = time.time() if timestamp is None else timestamp
        self._publisher.put(encode_frame(image, frame_id, stamp, self.pixel_format))

    def status(self, timeout_s: float = 2.0) -> dict[str, Any] | None:
        """The daemon's status JSON from the queryable, None if nobody answered in time."""
        for reply in self.session.get(self.status_key, timeout=timeout_s):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def close(self) -> None:
        """Undeclare and close the session."""
        for entity in (self._subscriber, self._publisher):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - best effort at shutdown; the session close follows
                pass
        self.session.close()

    def __enter__(self) -> "SimCamera":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
