"""The web station's MAVLink side (pymavlink): a ground station on one or more links that sends the camera
tracking commands as QGroundControl does and collects what the cameras answer.

- Identity: system 255, component 190 (MAV_COMP_ID_MISSIONPLANNER), HEARTBEAT as a ground station at
  1 Hz on every link, so autopilots route the cameras' answers to it.
- Commands: COMMAND_LONG to (system, camera component), coordinates normalised 0..1 from the image's
  top-left corner: MAV_CMD_CAMERA_TRACK_POINT (x, y, radius as a fraction of the image width),
  MAV_CMD_CAMERA_TRACK_RECTANGLE (top-left x, y, bottom-right x, y), MAV_CMD_CAMERA_STOP_TRACKING.
  No COMMAND_ACK within `ack_timeout_s`: sent again with `confirmation` + 1, up to `attempts` times.
  A refusal's reason is the STATUSTEXT the camera sent with it (the daemon sends it before the ACK).
- Feedback: CAMERA_TRACKING_IMAGE_STATUS (275) of every camera, requested with
  MAV_CMD_SET_MESSAGE_INTERVAL (QGroundControl asks for 2 Hz after a track command; the web station
  asks for it as soon as the operator looks at a camera, and leaves it on after a stop so IDLE shows).
- Several links (one per drone's radio, or one through a router): each system is answered on the
  link it was last heard on.

Threads: one receiver per link and one heartbeat thread; callbacks run on the receivers' threads.
"""
from __future__ import annotations

import collections
import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink: message ids > 255 (275) need MAVLink 2
from pymavlink import mavutil  # noqa: E402

MAV_TYPE_GCS = 6
MAV_TYPE_CAMERA = 30
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_CAMERA_TRACK_POINT = 2004
MAV_CMD_CAMERA_TRACK_RECTANGLE = 2005
MAV_CMD_CAMERA_STOP_TRACKING = 2010
CAMERA_TRACKING_IMAGE_STATUS = 275
COMMAND_NAMES = {MAV_CMD_CAMERA_TRACK_POINT: "TRACK_POINT", MAV_CMD_CAMERA_TRACK_RECTANGLE: "TRACK_RECTANGLE",
                 MAV_CMD_CAMERA_STOP_TRACKING: "STOP_TRACKING", MAV_CMD_SET_MESSAGE_INTERVAL: "SET_MESSAGE_INTERVAL"}
MAV_RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                    5: "IN_PROGRESS", 6: "CANCELLED", 7: "COMMAND_LONG_ONLY", 8: "COMMAND_INT_ONLY",
                    9: "UNSUPPORTED_MAV_FRAME"}
TRACKING_STATUS_FLAGS = ((1, "ACTIVE"), (2, "ERROR"), (4, "MTI"), (8, "COASTING"))
TRACKING_MODES = {0: "NONE", 1: "POINT", 2: "RECTANGLE"}
STATUSTEXT_CHUNK = 50
CAMERA_COMPONENTS = range(100, 106)  # MAV_COMP_ID_CAMERA .. CAMERA6


def tracking_status_name(flags: int) -> str:
    """275's tracking_status flags as text: IDLE, ACTIVE, ACTIVE|COASTING, ERROR, ..."""
    names = [name for bit, name in TRACKING_STATUS_FLAGS if flags & bit]
    return "|".join(names) if names else "IDLE"


@dataclass(frozen=True)
class ImageStatus:
    """One CAMERA_TRACKING_IMAGE_STATUS: flags, mode, rectangle (top-left x, y, bottom-right x, y; normalised,
    NaN unknown), and when it arrived (monotonic s)."""

    system_id: int
    component_id: int
    status: int
    mode: int
    rectangle: tuple[float, float, float, float]
    received_s: float

    def as_json(self) -> dict:
        """For the page: names, and the rectangle with NaN as null (JSON has no NaN)."""
        return {"system_id": self.system_id, "component_id": self.component_id, "status": self.status,
                "status_name": tracking_status_name(self.status), "mode": TRACKING_MODES.get(self.mode, str(self.mode)),
                "rectangle": [None if math.isnan(v) else v for v in self.rectangle]}


@dataclass(frozen=True)
class CommandOutcome:
    """What became of a command: the MAV_RESULT (None: no ACK after every attempt), its name, the camera's
    reason for a refusal (its STATUSTEXT; None if it sent none), attempts made."""

    command: int
    system_id: int
    component_id: int
    result: int | None
    reason: str | None
    attempts: int

    @property
    def result_name(self) -> str:
        if self.result is None:
            return "NO_ACK"
        return MAV_RESULT_NAMES.get(self.result, str(self.result))

    @property
    def accepted(self) -> bool:
        return self.result == 0

    def as_json(self) -> dict:
        return {"command": COMMAND_NAMES.get(self.command, str(self.command)), "system_id": self.system_id,
                "component_id": self.component_id, "result": self.result, "result_name": self.result_name,
                "reason": self.reason, "attempts": self.attempts}


@dataclass
class StatusTextAssembler:
    """STATUSTEXT (253) texts of one component: id 0 texts at once, MAVLink 2 chunked ones (same id,
    chunk_seq from 0) when the chunk holding a NUL arrives. Keeps the newest `limit` texts (time, severity, text)."""

    limit: int = 50
    texts: collections.deque = field(default_factory=lambda: collections.deque(maxlen=50))
    _chunks: dict = field(default_factory=dict)  # id -> {seq: text}

    def add(self, text_id: int, chunk_seq: int, raw: bytes | str, severity: int, now_s: float) -> str | None:
        """Add one message; returns a completed text (or None while chunks are missing)."""
        data = raw.encode("latin-1", "replace") if isinstance(raw, str) else bytes(raw)
        ends = b"\x00" in data or len(data) < STATUSTEXT_CHUNK
        piece = data.split(b"\x00", 1)[0].decode("ascii", "replace")
        if text_id == 0:
            text = piece
        else:
            parts = self._chunks.setdefault(text_id, {})
            parts[chunk_seq] = piece
            if not ends:
                if len(self._chunks) > 16:  # chunks of texts whose end never came
                    self._chunks.pop(next(iter(self._chunks)))
                return None
            pieces = self._chunks.pop(text_id)
            text = "".join(pieces.get(i, "[...]") for i in range(max(pieces) + 1))
        self.texts.append((now_s, severity, text))
        return text

    def since(self, start_s: float) -> list[str]:
        """Texts completed at or after start_s (monotonic), oldest first."""
        return [text for at, _sev, text in self.texts if at >= start_s]


SIGNING_EPOCH_S = 1420070400  # MAVLink 2 signing timestamps count 10-us units from 2015-01-01 UTC


def read_signing_key(path: str) -> bytes:
    """The 32-byte MAVLink 2 signing key in a key file (`jsar-service keygen`'s 64 hex characters, or 32 raw
    bytes); ValueError naming the file otherwise."""
    try:
        data = open(path, "rb").read()
    except OSError as exc:
        raise ValueError(f"--signing-key: cannot read {path}: {exc.strerror}") from exc
    try:
        key = bytes.fromhex(data.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = data
    if len(key) != 32:
        raise ValueError(f"--signing-key: {path} must hold 64 hex characters or 32 raw bytes")
    return key


class Link:
    """One pymavlink connection with a send lock (sends come from several threads); with signing_key, every
    message it sends is signed (MAVLink 2 signing, link id link_id). What it receives may be unsigned: the
    drone's autopilot may not sign its telemetry."""

    def __init__(self, url: str, system_id: int, component_id: int, signing_key: bytes | None = None,
                 link_id: int = 0) -> None:
        self.url = url
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=system_id, source_component=component_id,
                                                   autoreconnect=True)
        except Exception as exc:  # pymavlink raises OSError, ValueError, serial errors...
            raise ConnectionError(f"MAVLink: cannot open {url}: {exc}") from exc
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True, allow_unsigned_callback=lambda mav, msg_id: True,
                                    initial_timestamp=int((time.time() - SIGNING_EPOCH_S) * 1e5), link_id=link_id)
        self.lock = threading.Lock()
        self.send_errors = 0

    def send(self, msg: object) -> None:
        with self.lock:
            signing = self.conn.mav.signing
            if signing.sign_outgoing:  # pymavlink adds 10 us a message: keep up with the clock (receivers
                # refuse a new stream over a minute behind their own)
                signing.timestamp = max(signing.timestamp, int((time.time() - SIGNING_EPOCH_S) * 1e5))
            try:
                self.conn.mav.send(msg)
            except OSError:
                self.send_errors += 1  # udpin before anyone was heard, or the peer is gone: the retry resends


class MavlinkStation:
    """A ground station on `urls` (pymavlink URLs: udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, /dev/ttyX
    with ,BAUD). `on_status(ImageStatus)` and `on_text(system, component, severity, text)` are called on the
    receive threads."""

    def __init__(self, urls: list[str], system_id: int = 255, component_id: int = 190,
                 on_status: Callable[[ImageStatus], None] = lambda status: None,
                 on_text: Callable[[int, int, int, str], None] = lambda s, c, sev, text: None,
                 ack_timeout_s: float = 1.5, attempts: int = 3, signing_key: bytes | None = None) -> None:
        """signing_key: sign every message sent (the drone's 32-byte MAVLink 2 key); None = unsigned."""
        if not urls:
            raise ValueError("at least one MAVLink URL is needed")
        if not (ack_timeout_s > 0 and attempts >= 1):
            raise ValueError(f"ack_timeout_s must be > 0 and attempts >= 1, got {ack_timeout_s}, {attempts}")
        self.system_id, self.component_id = system_id, component_id
        self.on_status, self.on_text = on_status, on_text
        self.ack_timeout_s, self.attempts = ack_timeout_s, attempts
        self.links: list[Link] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        try:
            for index, url in enumerate(urls):
                self.links.append(Link(url, system_id, component_id, signing_key, link_id=index))
        except ConnectionError:
            self.close()
            raise
        self._lock = threading.RLock()  # re-entrant: wait_for predicates call the queries below
        self._changed = threading.Condition(self._lock)
        self._heard: dict[tuple[int, int], tuple[float, int]] = {}  # (sys, comp) -> (monotonic, MAV_TYPE)
        self._route: dict[int, Link] = {}  # system -> link it was last heard on
        self._statuses: dict[tuple[int, int], ImageStatus] = {}
        self._texts: dict[tuple[int, int], StatusTextAssembler] = collections.defaultdict(StatusTextAssembler)
        self._acks: collections.deque = collections.deque(maxlen=200)  # (monotonic, sys, comp, command, result)
        self._command_locks: dict[tuple[int, int], threading.Lock] = collections.defaultdict(threading.Lock)
        self._interval_asked: dict[tuple[int, int], float] = {}
        self.counters = collections.Counter()
        self._threads = [threading.Thread(target=self._receive, args=(link,), name=f"mavlink-rx-{i}", daemon=True)
                         for i, link in enumerate(self.links)]
        self._threads.append(threading.Thread(target=self._heartbeats, name="mavlink-heartbeat", daemon=True))
        for thread in self._threads:
            thread.start()

    # ----- threads ------------------------------------------------------------------------------
    def _heartbeats(self) -> None:
        while not self._stop.is_set():
            for link in self.links:
                link.send(link.conn.mav.heartbeat_encode(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE))
            self._stop.wait(1.0)

    def _receive(self, link: Link) -> None:
        while not self._stop.is_set():
            try:
                msg = link.conn.recv_match(blocking=True, timeout=0.2)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                self.counters["receive_errors"] += 1
                self._stop.wait(0.2)  # the link failed (serial unplugged...): autoreconnect, then read on
                continue
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.counters["bad_data"] += 1
                continue
            try:
                self._handle(link, msg, kind)
            except Exception:  # noqa: BLE001 - one odd message must not end the receiver
                self.counters["handling_errors"] += 1

    def _handle(self, link: Link, msg: object, kind: str) -> None:
        source = (msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[attr-defined]
        now = time.monotonic()
        status = text = None
        with self._lock:
            self._route[source[0]] = link
            if kind == "HEARTBEAT":
                self._heard[source] = (now, msg.type)  # type: ignore[attr-defined]
            elif kind == "CAMERA_TRACKING_IMAGE_STATUS":
                status = ImageStatus(source[0], source[1], int(msg.tracking_status), int(msg.tracking_mode),  # type: ignore[attr-defined]
                                     (msg.rec_top_x, msg.rec_top_y, msg.rec_bottom_x, msg.rec_bottom_y), now)  # type: ignore[attr-defined]
                self._statuses[source] = status
            elif kind == "COMMAND_ACK" and self._for_me(msg):
                self._acks.append((now, source[0], source[1], int(msg.command), int(msg.result)))  # type: ignore[attr-defined]
            elif kind == "STATUSTEXT":
                text = self._texts[source].add(int(getattr(msg, "id", 0)), int(getattr(msg, "chunk_seq", 0)),  # type: ignore[attr-defined]
                                               msg.text, int(msg.severity), now)  # type: ignore[attr-defined]
            self._changed.notify_all()
        if status is not None:
            self.on_status(status)
        if text is not None:
            self.on_text(source[0], source[1], int(msg.severity), text)  # type: ignore[attr-defined]

    def _for_me(self, ack: object) -> bool:
        """An ACK addressed to this station (MAVLink 1 style ACKs without a target are taken too)."""
        target_system = getattr(ack, "target_system", 0)
        target_component = getattr(ack, "target_component", 0)
        return target_system in (0, self.system_id) and target_component in (0, self.component_id)

    # ----- queries ------------------------------------------------------------------------------
    def cameras(self, max_age_s: float = 5.0) -> list[tuple[int, int]]:
        """(system, component) of the cameras (MAV_TYPE_CAMERA heartbeats, components 100-105) heard lately."""
        now = time.monotonic()
        with self._lock:
            return sorted(key for key, (at, mav_type) in self._heard.items()
                          if now - at <= max_age_s and (mav_type == MAV_TYPE_CAMERA or key[1] in CAMERA_COMPONENTS))

    def heard(self, system_id: int, component_id: int, max_age_s: float = 5.0) -> bool:
        """True if (system, component) sent a heartbeat within max_age_s."""
        with self._lock:
            entry = self._heard.get((system_id, component_id))
        return entry is not None and time.monotonic() - entry[0] <= max_age_s

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until predicate() holds (re-checked on every message received) or timeout_s passes."""
        with self._changed:
            return self._changed.wait_for(predicate, timeout=timeout_s)

    def status(self, system_id: int, component_id: int) -> ImageStatus | None:
        """The camera's newest 275, None before the first."""
        with self._lock:
            return self._statuses.get((system_id, component_id))

    # ----- commands -----------------------------------------------------------------------------
    def track_point(self, system_id: int, component_id: int, x: float, y: float, radius: float) -> CommandOutcome:
        """MAV_CMD_CAMERA_TRACK_POINT: x, y normalised 0..1 (top-left origin), radius a fraction of the width."""
        return self.command(system_id, component_id, MAV_CMD_CAMERA_TRACK_POINT, (x, y, radius, 0, 0, 0, 0))

    def track_rectangle(self, system_id: int, component_id: int, top_x: float, top_y: float, bottom_x: float,
                        bottom_y: float) -> CommandOutcome:
        """MAV_CMD_CAMERA_TRACK_RECTANGLE: top-left and bottom-right corners, normalised 0..1."""
        return self.command(system_id, component_id, MAV_CMD_CAMERA_TRACK_RECTANGLE,
                            (top_x, top_y, bottom_x, bottom_y, 0, 0, 0))

    def stop_tracking(self, system_id: int, component_id: int) -> CommandOutcome:
        """MAV_CMD_CAMERA_STOP_TRACKING."""
        return self.command(system_id, component_id, MAV_CMD_CAMERA_STOP_TRACKING, (0, 0, 0, 0, 0, 0, 0))

    def request_status(self, system_id: int, component_id: int, interval_s: float = 0.5,
                       every_s: float = 10.0) -> CommandOutcome | None:
        """Ask the camera for 275 every interval_s, unless asked within every_s (None then): cameras
        forget (restart) and other ground stations change it, so it is asked again now and then."""
        key = (system_id, component_id)
        now = time.monotonic()
        with self._lock:
            if now - self._interval_asked.get(key, -math.inf) < every_s:
                return None
            self._interval_asked[key] = now
        outcome = self.command(system_id, component_id, MAV_CMD_SET_MESSAGE_INTERVAL,
                               (CAMERA_TRACKING_IMAGE_STATUS, int(interval_s * 1e6), 0, 0, 0, 0, 0))
        if not outcome.accepted:
            with self._lock:
                self._interval_asked.pop(key, None)  # ask again next time
        return outcome

    def command(self, system_id: int, component_id: int, command: int, params: tuple[float, ...]) -> CommandOutcome:
        """COMMAND_LONG to (system, component), resent (confirmation + 1) while no ACK comes within
        ack_timeout_s, at most `attempts` times. Blocks until the outcome; one command per camera at a time."""
        if len(params) != 7:
            raise ValueError(f"COMMAND_LONG takes 7 params, got {len(params)}")
        with self._command_locks[(system_id, component_id)]:
            started = time.monotonic()
            for attempt in range(self.attempts):
                link = self._link_for(system_id)
                sent = time.monotonic()
                link.send(link.conn.mav.command_long_encode(system_id, component_id, command, attempt, *params))
                ack = self._wait_ack(system_id, component_id, command, sent, self.ack_timeout_s)
                if ack is not None:
                    reason = None if ack == 0 else self._reason(system_id, component_id, started)
                    self.counters["acks"] += 1
                    return CommandOutcome(command, system_id, component_id, ack, reason, attempt + 1)
            self.counters["no_ack"] += 1
            return CommandOutcome(command, system_id, component_id, None, None, self.attempts)

    def _link_for(self, system_id: int) -> Link:
        with self._lock:
            return self._route.get(system_id, self.links[0])

    def _wait_ack(self, system_id: int, component_id: int, command: int, since_s: float, timeout_s: float) -> int | None:
        """The result of the first ACK for `command` from (system, component) received after since_s."""
        found: list[int] = []

        def arrived() -> bool:
            for at, sysid, compid, cmd, result in self._acks:
                if at >= since_s and (sysid, compid, cmd) == (system_id, component_id, command) and result != 5:
                    found.append(result)  # IN_PROGRESS (5) is not final: keep waiting
                    return True
            return False
        with self._changed:
            self._changed.wait_for(arrived, timeout=timeout_s)
        return found[0] if found else None

    def _reason(self, system_id: int, component_id: int, since_s: float, grace_s: float = 0.3) -> str | None:
        """The camera's STATUSTEXT sent with a refusal: texts since the command went out (it comes before the
        ACK; a little grace for one that comes after)."""
        key = (system_id, component_id)

        def texts() -> list[str]:
            return self._texts[key].since(since_s) if key in self._texts else []
        with self._changed:
            self._changed.wait_for(lambda: bool(texts()), timeout=grace_s)
            found = texts()
        return "; ".join(found) if found else None

    def close(self) -> None:
        """Stop the threads and close the links."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=1.0)
        for link in self.links:
            try:
                link.conn.close()
            except OSError:
                pass
