"""Zenoh adapter: session from config, per-frame track telemetry and the status queryable.

Keys: `<prefix>/track` (one JSON sample per processed frame, loop.FrameReport.as_json) and
`<prefix>/status` (queryable: JSON status, counters and effective configuration, the session's links).
The session takes Zenoh's own TLS link and access control from `zenoh.tls` / `zenoh.access`
(docs/security.md); endpoints open beyond loopback without TLS are logged at start, and the loss of the
link to the connect endpoints (a router) as it happens.
"""
from __future__ import annotations

import ipaddress
import json
import logging
import threading
import time
from typing import Any, Callable

import zenoh

from service.config import ZenohAccessConfig, ZenohConfig, ZenohTlsConfig, endpoint_protocol

log = logging.getLogger("service.telemetry")


ENCRYPTED_PROTOCOLS = ("tls", "quic")  # Zenoh links that run over TLS
LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe", "vsock")  # links that never leave the machine
START_GRACE_S = 3.0  # s: a connect endpoint not reached this long after start is logged (Zenoh's own retry goes on)


def zenoh_config(config: ZenohConfig) -> zenoh.Config:
    """zenoh.Config with mode, endpoints, multicast scouting, TLS link and access control from our config."""
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps(config.mode))
    zc.insert_json5("listen/endpoints", json.dumps(list(config.listen)))
    zc.insert_json5("connect/endpoints", json.dumps(list(config.connect)))
    zc.insert_json5("scouting/multicast/enabled", json.dumps(config.multicast_scouting))
    if config.tls.enabled:
        for key, value in tls_section(config.tls).items():
            zc.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    if config.access.enabled:
        zc.insert_json5("access_control", json.dumps(access_control_section(config.access)))
    return zc


def tls_section(tls: ZenohTlsConfig) -> dict[str, Any]:
    """Zenoh's transport.link.tls keys (1.x names): one certificate for listening and for connecting."""
    return {"root_ca_certificate": tls.root_ca_certificate,
            "listen_certificate": tls.certificate, "listen_private_key": tls.private_key,
            "connect_certificate": tls.certificate, "connect_private_key": tls.private_key,
            "enable_mtls": tls.enable_mtls, "verify_name_on_connect": tls.verify_name_on_connect}


def access_control_section(access: ZenohAccessConfig) -> dict[str, Any]:
    """Zenoh's access_control section; empty lists left out (Zenoh refuses an empty list)."""
    def entry(item: object) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in vars(item).items() if v not in ((), "")}
    return {"enabled": access.enabled, "default_permission": access.default_permission,
            "rules": [entry(r) for r in access.rules], "subjects": [entry(s) for s in access.subjects],
            "policies": [entry(p) for p in access.policies]}


def endpoint_is_loopback(endpoint: str) -> bool:
    """True when a Zenoh endpoint `proto/HOST:PORT` (`?metadata`, `#config` allowed) names a loopback host."""
    address = endpoint.partition("/")[2].split("?")[0].split("#")[0]
    host = address.rsplit(":", 1)[0] if ":" in address else address
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def insecure_endpoints(config: ZenohConfig) -> list[tuple[str, str, str]]:
    """(key, endpoint, why) for each listen / connect endpoint that reaches beyond loopback unencrypted, or
    that takes peers without a certificate (TLS without mTLS) beyond loopback."""
    found = []
    for section in ("listen", "connect"):
        for i, endpoint in enumerate(getattr(config, section)):
            protocol = endpoint_protocol(endpoint)
            if protocol in LOCAL_PROTOCOLS or endpoint_is_loopback(endpoint):
                continue
            if protocol not in ENCRYPTED_PROTOCOLS:
                found.append((f"zenoh.{section}[{i}]", endpoint,
                              "beyond loopback without TLS: anyone on that network can read the telemetry and "
                              "video and publish into the daemon; use tls/HOST:PORT with zenoh.tls"))
            elif section == "listen" and not config.tls.enable_mtls:
                found.append(("zenoh.tls.enable_mtls", endpoint,
                              "TLS without client certificates: any peer can connect; set it to true"))
    return found


def open_session(config: ZenohConfig) -> zenoh.Session:
    """Open a Zenoh session, first logging a warning for each endpoint open beyond loopback without TLS;
    ConnectionError naming the endpoints on failure."""
    for key, endpoint, why in insecure_endpoints(config):
        log.warning('event=zenoh_unencrypted key=%s endpoint=%s reason="%s"', key, endpoint, why)
    try:
        return zenoh.open(zenoh_config(config))
    except Exception as exc:  # zenoh.ZError
        raise ConnectionError(f"zenoh: cannot open session (mode {config.mode}, listen {list(config.listen)}, "
                              f"connect {list(config.connect)}): {exc}") from exc


def endpoint_port(endpoint: str) -> tuple[str, str] | None:
    """`tcp/127.0.0.1:7447` (`?metadata`, `#config` allowed) -> ("tcp", "7447"); None without a port."""
    protocol, _, address = endpoint.partition("/")
    address = address.split("?")[0].split("#")[0]
    if ":" not in address:
        return None
    return protocol, address.rsplit(":", 1)[1]


def is_outgoing(link_src: str, listen: tuple[str, ...]) -> bool:
    """Whether a link was opened by this node (towards a connect endpoint) rather than accepted: an accepted
    link's local locator (`src`) has a listen endpoint's protocol and port, an opened one an ephemeral port."""
    return endpoint_port(link_src) not in {endpoint_port(e) for e in listen}


class ZenohLinks:
    """The session's links (Zenoh link events, on Zenoh's threads): how many go out to `zenoh.connect`
    endpoints (a router, a listening station) and how many were accepted; the loss of the last outgoing
    link is logged at once (event=zenoh_disconnected), and its return (event=zenoh_reconnected). Zenoh
    itself reconnects to the connect endpoints; this only watches."""

    def __init__(self, session: zenoh.Session, config: ZenohConfig,
                 clock: Callable[[], float] | None = None) -> None:
        self._config = config
        self._clock = clock or time.monotonic
        self._lock = threading.Lock()
        self._out: set[tuple[str, str, str]] = set()  # (remote zid, src, dst)
        self._in: set[tuple[str, str, str]] = set()
        self.disconnections = 0
        self._lost_at: float | None = self._clock() if config.connect else None
        self._connected_once = False
        self._listener = session.info.declare_link_events_listener(self._on_event, history=True)
        # the links opened during zenoh.open arrive as events shortly after; an endpoint still unreached after
        # START_GRACE_S is reported once (later losses are reported as they happen)
        self._start_check = threading.Timer(START_GRACE_S, self._check_start)
        self._start_check.daemon = True
        if config.connect:
            self._start_check.start()

    def _check_start(self) -> None:
        if self.snapshot()["state"] == "disconnected" and not self._connected_once:
            log.warning("event=zenoh_disconnected key=zenoh.connect endpoints=%s: no connect endpoint reached "
                        "%.0f s after start; Zenoh keeps trying", ",".join(self._config.connect), START_GRACE_S)

    def _on_event(self, event: Any) -> None:
        link = event.link
        key = (str(link.zid), str(link.src), str(link.dst))
        links = self._out if is_outgoing(key[1], self._config.listen) else self._in
        with self._lock:
            before = len(self._out)
            if event.kind == zenoh.SampleKind.PUT:
                links.add(key)
            else:
                links.discard(key)
            after = len(self._out)
            now = self._clock()
            if not self._config.connect or (before == 0) == (after == 0):
                return
            if after == 0:
                self.disconnections += 1
                self._lost_at = now
                change, down_s = "lost", 0.0
            else:
                down_s = now - self._lost_at if self._lost_at is not None else 0.0
                self._lost_at = None
                change = "reconnected" if self._connected_once else "connected"
                self._connected_once = True
        endpoints = ",".join(self._config.connect)
        if change == "lost":
            log.warning("event=zenoh_disconnected key=zenoh.connect endpoints=%s remote=%s: no link to any "
                        "connect endpoint; telemetry and video reach no one through it until Zenoh reconnects",
                        endpoints, key[2])
        elif change == "connected":
            log.info("event=zenoh_connected endpoints=%s remote=%s", endpoints, key[2])
        else:
            log.info("event=zenoh_reconnected endpoints=%s remote=%s down_s=%.2f", endpoints, key[2], down_s)

    def snapshot(self) -> dict[str, Any]:
        """{"state": connected / disconnected (no link to any connect endpoint) / listening (none configured),
        "links_out", "links_in", "disconnections", "disconnected_s": seconds since the loss (None while connected)}."""
        with self._lock:
            out, accepted, lost_at = len(self._out), len(self._in), self._lost_at
        state = "listening" if not self._config.connect else "connected" if out else "disconnected"
        return {"state": state, "links_out": out, "links_in": accepted, "disconnections": self.disconnections,
                "disconnected_s": (round(self._clock() - lost_at, 3)
                                  if state == "disconnected" and lost_at is not None else None)}

    def close(self) -> None:
        self._start_check.cancel()
        try:
            self._listener.undeclare()
        except Exception:  # noqa: BLE001 - already closed at shutdown
            pass


class Telemetry:
    """Publishes track samples and answers status queries on an open session; the status answer carries the
    session's links (`zenoh`, ZenohLinks.snapshot) when the config is given."""

    def __init__(self, session: zenoh.Session, prefix: str, status: Callable[[], dict[str, Any]],
                 config: ZenohConfig | None = None) -> None:
        self.track_key = f"{prefix}/track"
        self.status_key = f"{prefix}/status"
        self._status = status
        self.links = ZenohLinks(session, config) if config is not None else None
        self._publisher = session.declare_publisher(self.track_key)
        self._queryable = session.declare_queryable(self.status_key, self._answer)
        self.published = 0

    def publish(self, sample: dict[str, Any]) -> None:
        self._publisher.put(json.dumps(sample))
        self.published += 1

    def _answer(self, query: zenoh.Query) -> None:
        try:
            status = self._status()
            if self.links is not None:
                status["zenoh"] = self.links.snapshot()
            query.reply(self.status_key, json.dumps(status))
        except Exception:  # noqa: BLE001 - a failed reply must not kill Zenoh's callback thread
            log.exception("event=status_query_failed")

    def close(self) -> None:
        if self.links is not None:
            self.links.close()
        for entity in (self._queryable, self._publisher):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - already closed at shutdown
                pass
