"""Zenoh adapter: session from config, per-frame track telemetry and the status queryable.

Keys: `<prefix>/track` (one JSON sample per processed frame, loop.FrameReport.as_json) and
`<prefix>/status` (queryable: JSON status, counters and effective configuration).
"""
from __future__ import annotations

import json
import logging
from typing import Any, Callable

import zenoh

from service.config import ZenohConfig

log = logging.getLogger("service.telemetry")


def zenoh_config(config: ZenohConfig) -> zenoh.Config:
    """zenoh.Config with mode, endpoints and multicast scouting from our config."""
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps(config.mode))
    zc.insert_json5("listen/endpoints", json.dumps(list(config.listen)))
    zc.insert_json5("connect/endpoints", json.dumps(list(config.connect)))
    zc.insert_json5("scouting/multicast/enabled", json.dumps(config.multicast_scouting))
    return zc


def open_session(config: ZenohConfig) -> zenoh.Session:
    """Open a Zenoh session; ConnectionError naming the endpoints on failure."""
    try:
        return zenoh.open(zenoh_config(config))
    except Exception as exc:  # zenoh.ZError
        raise ConnectionError(f"zenoh: cannot open session (mode {config.mode}, listen {list(config.listen)}, "
                              f"connect {list(config.connect)}): {exc}") from exc


class Telemetry:
    """Publishes track samples and answers status queries on an open session."""

    def __init__(self, session: zenoh.Session, prefix: str, status: Callable[[], dict[str, Any]]) -> None:
        self.track_key = f"{prefix}/track"
        self.status_key = f"{prefix}/status"
        self._status = status
        self._publisher = session.declare_publisher(self.track_key)
        self._queryable = session.declare_queryable(self.status_key, self._answer)
        self.published = 0

    def publish(self, sample: dict[str, Any]) -> None:
        self._publisher.put(json.dumps(sample))
        self.published += 1

    def _answer(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.status_key, json.dumps(self._status()))
        except Exception:  # noqa: BLE001 - a failed reply must not kill Zenoh's callback thread
            log.exception("event=status_query_failed")

    def close(self) -> None:
        for entity in (self._queryable, self._publisher):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - already closed at shutdown
                pass
