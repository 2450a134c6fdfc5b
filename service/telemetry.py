"""Zenoh adapter: session from config, per-frame track telemetry and the status queryable.

Keys: `<prefix>/track` (one JSON sample per processed frame, loop.FrameReport.as_json) and
`<prefix>/status` (queryable: JSON status, counters and effective configuration).
"""
from __future__ import annotations

import ipaddress
import json
import logging
from typing import Any, Callable

import zenoh

from service.config import ZenohAccessConfig, ZenohConfig, ZenohTlsConfig, endpoint_protocol

log = logging.getLogger("service.telemetry")


ENCRYPTED_PROTOCOLS = ("tls", "quic")  # Zenoh links that run over TLS
LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe", "vsock")  # links that never leave the machine


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
