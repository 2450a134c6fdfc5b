"""The web station's Zenoh side: every tracking daemon reachable on the Zenoh network, one key prefix each.

Keys (the daemon's public contract, docs/video.md and config.yaml's `zenoh:`):
- `<prefix>/track`: one JSON sample per tracked frame (frame_id, capture_time, image_size, box_px,
  box_norm (x, y, w, h normalised), score, state tracking / lost / recovered / idle, coasting, latency_ms);
- `<prefix>/camera/preview`: the tracked frames as JPEG (gcs.preview), frame id and capture time those
  of the frame's track sample;
- `<prefix>/status` (queryable): status JSON, including `mavlink_system_id` and `config.mavlink.component_id`:
  the MAVLink camera that commands for this drone go to; `autopilot.state` (waiting_for_heartbeat / connected /
  heartbeat_lost) and `autopilot.system_id`, `config.mavlink.system_id` (0: learnt from the heartbeat) and
  `config.gimbal.backend` (ardupilot / px4 / none): whether the daemon has an autopilot to send gimbal commands to.

A drone appears when its track samples or its status answer arrive (`**/track` is subscribed, `**/status`
queried every `status_every_s`). Previews are subscribed only for the drones a page watches (a 640x480
preview is ~0.3 MB/s at 15 fps; the fleet's telemetry is small).
"""
from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import zenoh

from gcs.preview import PREVIEW_SUFFIX, PreviewFrame, decode_preview, drone_prefix
from gcs.zenoh_tls import ZenohTls, check_endpoints, is_outgoing

log = logging.getLogger("gcs.drones")
TRACK_SUFFIX = "track"
STATUS_SUFFIX = "status"


@dataclass(frozen=True)
class ZenohSettings:
    """How the station joins the Zenoh network: mode (peer / client), endpoints to connect to (a daemon's
    listen endpoint, or a router's), endpoints to listen on, multicast scouting (off: explicit endpoints),
    mutual TLS for tls/HOST:PORT endpoints (gcs.zenoh_tls)."""

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    mode: str = "peer"
    multicast_scouting: bool = False
    tls: ZenohTls | None = None

    def __post_init__(self) -> None:
        self.unencrypted()  # ValueError for a tls/ endpoint without certificates
        if self.mode not in ("peer", "client"):
            raise ValueError(f"zenoh mode must be peer or client, got {self.mode!r}")
        if not (self.connect or self.listen or self.multicast_scouting):
            raise ValueError("zenoh: give an endpoint to connect to (--zenoh tcp/HOST:7447), one to listen on, "
                             "or turn multicast scouting on: otherwise no daemon can be reached")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh client mode needs an endpoint to connect to (a router or a peer)")

    def unencrypted(self) -> list[str]:
        """Warnings for endpoints that reach beyond loopback without TLS (ValueError: tls/ without certificates)."""
        return check_endpoints(self.connect + self.listen, self.tls,
                               self.tls.option if self.tls is not None else "--zenoh-tls")

    def to_zenoh(self) -> zenoh.Config:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps(self.mode))
        config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        config.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        if self.tls is not None:
            self.tls.insert_into(config)
        return config


@dataclass
class Drone:
    """What is known of one daemon (its Zenoh key prefix)."""

    prefix: str
    system_id: int | None = None  # MAVLink system of its camera (from the status queryable)
    component_id: int | None = None  # MAVLink component of its camera
    daemon_status: str | None = None  # ok / starting / error, from the status queryable
    autopilot: dict[str, Any] | None = None  # from the status queryable, see autopilot_summary
    last_track: dict[str, Any] | None = None
    last_track_s: float | None = None  # monotonic
    last_status_s: float | None = None
    last_preview_s: float | None = None
    previews: int = 0
    malformed: int = 0
    stale: bool = False  # the station's link to the Zenoh network went down since it was last heard

    def summary(self, now_s: float, online_s: float = 5.0, link_up: bool = True) -> dict[str, Any]:
        """For the page's drone list; offline at once when the station's Zenoh link is down (`zenoh_link`)."""
        track = self.last_track or {}
        heard = [t for t in (self.last_track_s, self.last_status_s, self.last_preview_s) if t is not None]
        online = link_up and not self.stale and bool(heard) and now_s - max(heard) <= online_s
        return {"prefix": self.prefix, "system_id": self.system_id, "component_id": self.component_id,
                "daemon_status": self.daemon_status, "online": online, "zenoh_link": "up" if link_up else "lost",
                "state": track.get("state"), "coasting": bool(track.get("coasting")), "score": track.get("score"),
                "previews": self.previews, "autopilot": self.autopilot}


def autopilot_summary(status: dict[str, Any]) -> dict[str, Any] | None:
    """What a daemon's status answer says about its autopilot and gimbal: {"state": waiting_for_heartbeat /
    connected / heartbeat_lost, "system_id": the autopilot's (None until heard), "configured_system_id":
    config.mavlink.system_id (0: learnt from the heartbeat), "gimbal_backend": ardupilot / px4 / none,
    "gimbal_commands": "sent" / "held" / "none", "gimbal_attitude": True once a gimbal device reported its attitude
    to the daemon, False before, None from a daemon that does not say}; None if the answer has no `autopilot`
    part (an older daemon).

    The daemon sends gimbal commands once it knows a system id to send them to (heard, or configured); with
    none, and while the heartbeat of an autopilot heard before is lost, they are held."""
    autopilot = status.get("autopilot")
    if not isinstance(autopilot, dict):
        return None
    config = status.get("config") if isinstance(status.get("config"), dict) else {}
    mavlink = config.get("mavlink") if isinstance(config.get("mavlink"), dict) else {}
    gimbal = config.get("gimbal") if isinstance(config.get("gimbal"), dict) else {}
    system_id = autopilot.get("system_id") or None
    configured = mavlink.get("system_id") or 0
    backend = gimbal.get("backend")
    lost = autopilot.get("state") == "heartbeat_lost"
    commands = "none" if backend == "none" else "sent" if (system_id or configured) and not lost else "held"
    heard = autopilot.get("gimbal_attitude_heard")
    return {"state": autopilot.get("state"), "system_id": system_id, "configured_system_id": configured,
            "gimbal_backend": backend, "gimbal_commands": commands,
            "gimbal_attitude": heard if isinstance(heard, bool) else None}


@dataclass
class DroneDirectory:
    """The drones on the Zenoh network; `on_track(prefix, sample)` and `on_preview(prefix, frame, payload)`
    are called on Zenoh's threads."""

    settings: ZenohSettings
    on_track: Callable[[str, dict[str, Any]], None] = lambda prefix, sample: None
    on_preview: Callable[[str, PreviewFrame, bytes], None] = lambda prefix, frame, payload: None
    status_every_s: float = 2.0
    drones: dict[str, Drone] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._lock = threading.RLock()  # re-entrant: wait_for predicates call summaries()
        self._changed = threading.Condition(self._lock)
        self._watchers: dict[str, int] = {}
        self._preview_subs: dict[str, Any] = {}
        self._stop = threading.Event()
        self.status_rounds = 0  # completed status queries: after one, the list holds every daemon that answers
        # links this station opened to its --zenoh endpoints (a router, a daemon): none left = link down
        self._links_out: set[tuple[str, str, str]] = set()
        self.link_up = not self.settings.connect  # without connect endpoints there is no link of ours to lose
        self.disconnections = 0
        self._lost_at: float | None = None
        try:
            self.session = zenoh.open(self.settings.to_zenoh())
        except Exception as exc:  # zenoh.ZError: bad endpoint, port in use
            raise ConnectionError(f"zenoh: cannot open a session ({self.settings}): {exc}") from exc
        self._link_listener = self.session.info.declare_link_events_listener(self._on_link, history=True)
        self._track_sub = self.session.declare_subscriber(f"**/{TRACK_SUFFIX}", self._on_track_sample)
        self._poller = threading.Thread(target=self._poll_status, name="zenoh-status", daemon=True)
        self._poller.start()

    def _drone(self, prefix: str) -> Drone:
        drone = self.drones.get(prefix)
        if drone is None:
            drone = self.drones[prefix] = Drone(prefix)
            log.info("event=drone_found prefix=%s", prefix)
        return drone

    # ----- Zenoh callbacks ----------------------------------------------------------------------
    def _on_link(self, event: Any) -> None:
        """A link opened or closed: the loss of the last link to the --zenoh endpoints is logged at once and
        every drone shown offline until it is heard again; Zenoh reconnects by itself."""
        link = event.link
        key = (str(link.zid), str(link.src), str(link.dst))
        if not self.settings.connect or not is_outgoing(key[1], self.settings.listen):
            return
        with self._changed:
            was_up = bool(self._links_out)
            if event.kind == zenoh.SampleKind.PUT:
                self._links_out.add(key)
            else:
                self._links_out.discard(key)
            up = bool(self._links_out)
            if up == was_up:
                return
            self.link_up = up
            now = time.monotonic()
            down_s = now - self._lost_at if up and self._lost_at is not None else None
            if not up:
                self.disconnections += 1
                self._lost_at = now
                for drone in self.drones.values():
                    drone.stale = True
            self._changed.notify_all()
        endpoints = ",".join(self.settings.connect)
        if not up:
            log.warning("event=zenoh_disconnected endpoints=%s remote=%s: no drone can be heard or seen until "
                        "Zenoh reconnects", endpoints, key[2])
        elif down_s is None:
            log.info("event=zenoh_connected endpoints=%s remote=%s", endpoints, key[2])
        else:
            log.info("event=zenoh_reconnected endpoints=%s remote=%s down_s=%.2f", endpoints, key[2], down_s)

    def _heard(self, drone: Drone) -> None:
        """Called under the lock whenever a drone is heard: one that was cut off by a link loss is back."""
        if drone.stale:
            drone.stale = False
            log.info("event=drone_back prefix=%s", drone.prefix)

    def _on_track_sample(self, sample: zenoh.Sample) -> None:
        prefix = drone_prefix(str(sample.key_expr), TRACK_SUFFIX)
        if prefix is None:
            return
        try:
            track = json.loads(sample.payload.to_bytes())
            int(track["frame_id"])
        except (ValueError, KeyError, TypeError):
            with self._lock:
                self._drone(prefix).malformed += 1
            return
        with self._changed:
            drone = self._drone(prefix)
            drone.last_track, drone.last_track_s = track, time.monotonic()
            self._heard(drone)
            self._changed.notify_all()
        self.on_track(prefix, track)

    def _on_preview_sample(self, sample: zenoh.Sample) -> None:
        prefix = drone_prefix(str(sample.key_expr), PREVIEW_SUFFIX)
        if prefix is None:
            return
        payload = sample.payload.to_bytes()
        try:
            frame = decode_preview(payload)
        except ValueError as exc:
            with self._lock:
                drone = self._drone(prefix)
                drone.malformed += 1
                count = drone.malformed
            if count == 1:
                log.warning('event=preview_malformed prefix=%s error="%s"', prefix, exc)
            return
        with self._changed:
            drone = self._drone(prefix)
            drone.previews += 1
            drone.last_preview_s = time.monotonic()
            self._heard(drone)
            self._changed.notify_all()
        self.on_preview(prefix, frame, payload)

    def _poll_status(self) -> None:
        while not self._stop.is_set():
            try:
                self.refresh_status()
            except Exception as exc:  # noqa: BLE001 - a failed query is retried at the next poll
                log.warning('event=status_query_failed error="%s"', exc)
            self._stop.wait(self.status_every_s)

    def refresh_status(self, timeout_s: float = 1.0) -> None:
        """Query every daemon's `<prefix>/status` once; learn its MAVLink camera and health."""
        replies = self.session.get(f"**/{STATUS_SUFFIX}", target=zenoh.QueryTarget.ALL, timeout=timeout_s)
        for reply in replies:
            if reply.ok is None:
                continue
            prefix = drone_prefix(str(reply.ok.key_expr), STATUS_SUFFIX)
            if prefix is None:
                continue
            try:
                status = json.loads(reply.ok.payload.to_bytes())
                system_id = int(status["mavlink_system_id"])
                component_id = int(status["config"]["mavlink"]["component_id"])
            except (ValueError, KeyError, TypeError):
                with self._lock:
                    self._drone(prefix).malformed += 1
                continue
            with self._changed:
                drone = self._drone(prefix)
                drone.system_id, drone.component_id = system_id, component_id
                drone.daemon_status = str(status.get("status"))
                drone.autopilot = autopilot_summary(status)
                drone.last_status_s = time.monotonic()
                self._heard(drone)
                self._changed.notify_all()
        with self._changed:
            self.status_rounds += 1
            self._changed.notify_all()

    # ----- the pages' interest ------------------------------------------------------------------
    def watch(self, prefix: str) -> None:
        """Subscribe to the drone's preview (counted: one subscription however many pages watch it)."""
        with self._lock:
            self._watchers[prefix] = self._watchers.get(prefix, 0) + 1
            if prefix in self._preview_subs:
                return
        sub = self.session.declare_subscriber(f"{prefix}/{PREVIEW_SUFFIX}", self._on_preview_sample)
        with self._lock:
            self._preview_subs[prefix] = sub

    def unwatch(self, prefix: str) -> None:
        """One page fewer watches the drone; the last one undeclares the preview subscription."""
        with self._lock:
            count = self._watchers.get(prefix, 0) - 1
            if count > 0:
                self._watchers[prefix] = count
                return
            self._watchers.pop(prefix, None)
            sub = self._preview_subs.pop(prefix, None)
        if sub is not None:
            sub.undeclare()

    def summaries(self) -> list[dict[str, Any]]:
        """The drone list, sorted by prefix; a MAVLink identity two drones claim is flagged (`conflict`)."""
        now = time.monotonic()
        with self._lock:
            items = [drone.summary(now, link_up=self.link_up) for _, drone in sorted(self.drones.items())]
        ids = [(d["system_id"], d["component_id"]) for d in items if d["system_id"] is not None]
        for item in items:
            key = (item["system_id"], item["component_id"])
            item["conflict"] = item["system_id"] is not None and ids.count(key) > 1
        return items

    def target(self, prefix: str) -> tuple[int, int]:
        """The MAVLink (system, component) of the drone's camera; LookupError naming why there is none."""
        summaries = {d["prefix"]: d for d in self.summaries()}
        drone = summaries.get(prefix)
        if drone is None:
            raise LookupError(f"no drone {prefix!r} on the Zenoh network")
        if drone["system_id"] is None:
            raise LookupError(f"{prefix}: its status has not answered yet (MAVLink identity unknown)")
        if drone["conflict"]:
            raise LookupError(f"{prefix}: another drone also announces MAVLink system {drone['system_id']} "
                              f"component {drone['component_id']}: refusing to command the wrong one")
        return drone["system_id"], drone["component_id"]

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until predicate() (evaluated under the lock) holds or timeout_s passes."""
        with self._changed:
            return self._changed.wait_for(predicate, timeout=timeout_s)

    def close(self) -> None:
        """Stop polling, undeclare, close the session."""
        self._stop.set()
        self._poller.join(timeout=3.0)
        with self._lock:
            subs = [self._link_listener, self._track_sub, *self._preview_subs.values()]
            self._preview_subs.clear()
        for sub in subs:
            try:
                sub.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self.session.close()
