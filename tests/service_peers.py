"""Loopback MAVLink peers and helpers for the service tests (no tests here).

AutopilotPeer: a minimal autopilot/router written for the tests: two UDP ports (one for the service,
one for the ground station), heartbeats with a configurable flight mode, forwards packets between
the links except those addressed only to itself, records what the service sends.
GroundStation: a pymavlink ground-station peer (udpout to the autopilot's ground-station port).
"""
from __future__ import annotations

import functools
import os
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20.common import MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_TYPE_QUADROTOR  # noqa: E402

from service.config import ServiceConfig, config_from_mapping  # noqa: E402
from tests.helpers import Background  # noqa: E402


@dataclass
class Received:
    """A message and its arrival time (time.monotonic())."""

    msg: object
    at: float


class Recorder:
    """Thread-safe message log with waiting on a predicate (no sleeps)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.items: list[Received] = []

    def add(self, msg: object) -> None:
        with self._cond:
            self.items.append(Received(msg, time.monotonic()))
            self._cond.notify_all()

    def of(self, kind: str) -> list[Received]:
        with self._cond:
            return [r for r in self.items if r.msg.get_type() == kind]

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(predicate, timeout=timeout_s)


class UdpLink:
    """A UDP port bound on loopback that answers every address it has heard from (like udpin)."""

    def __init__(self, port: int, system: int, component: int) -> None:
        from pymavlink.dialects.v20 import common as dialect

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)  # bursts (the flood test) wait here
        self.sock.settimeout(0.1)
        self.mav = dialect.MAVLink(self, srcSystem=system, srcComponent=component)
        self.parser = dialect.MAVLink(None)
        self.parser.robust_parsing = True
        self._clients: set[tuple[str, int]] = set()
        self._lock = threading.Lock()

    def write(self, data: bytes) -> None:
        with self._lock:
            clients = list(self._clients)
        for address in clients:
            self.sock.sendto(data, address)

    def receive(self) -> list[object]:
        """Messages in the next datagram (empty on timeout or garbage)."""
        try:
            data, address = self.sock.recvfrom(65536)
        except socket.timeout:
            return []
        with self._lock:
            self._clients.add(address)
        try:
            return [m for m in (self.parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
        except Exception:  # noqa: BLE001 - garbage on the wire is not the peer's problem
            return []

    def close(self) -> None:
        self.sock.close()


class AutopilotPeer(Background):
    """System `system_id`, component 1. Links: 'service' (udpin on service_port), 'gcs' (udpin on gcs_port)."""

    def __init__(self, service_port: int, gcs_port: int, system_id: int = 1,
                 autopilot: int = MAV_AUTOPILOT_ARDUPILOTMEGA, custom_mode: int = 0,
                 heartbeat_hz: float = 10.0) -> None:
        self.system_id = system_id
        self.autopilot = autopilot
        self.custom_mode = custom_mode
        self.heartbeats_on = True
        self.gimbal_primary: tuple[int, int] | None = None  # set: the peer reports GIMBAL_MANAGER_STATUS (PX4-like)
        self.extra_periodic: list[Callable[[object], object]] = []  # msg builders sent with each heartbeat
        self.links = {"service": UdpLink(service_port, system_id, 1), "gcs": UdpLink(gcs_port, system_id, 1)}
        self.from_service = Recorder()
        self._period = 1.0 / heartbeat_hz
        self._lock = threading.Lock()
        super().__init__(*(functools.partial(self._receive, name) for name in self.links), self._beat)

    def release(self) -> None:
        for conn in self.links.values():
            conn.close()

    def send(self, link: str, msg: object) -> None:
        with self._lock:
            self.links[link].mav.send(msg)  # dropped until the peer has sent to us (udpin)

    def _handle_own(self, link: str, msg: object) -> None:
        """PX4-like gimbal manager: MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (1001) sets the primary controller."""
        if msg.get_type() == "COMMAND_LONG" and msg.command == 1001:
            self.gimbal_primary = (int(msg.param1), int(msg.param2))
            conn = self.links[link]
            self.send(link, conn.mav.command_ack_encode(1001, 0, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _beat(self) -> None:
        while not self._stop.wait(self._period):
            if not self.heartbeats_on:
                continue
            for name, conn in self.links.items():
                self.send(name, conn.mav.heartbeat_encode(MAV_TYPE_QUADROTOR, self.autopilot, 1, self.custom_mode, 4))
                if self.gimbal_primary is not None:  # GIMBAL_MANAGER_STATUS: who is in control
                    self.send(name, conn.mav.gimbal_manager_status_encode(0, 0, 0, *self.gimbal_primary, 0, 0))
                for build in self.extra_periodic:
                    self.send(name, build(conn.mav))

    def _receive(self, name: str) -> None:
        conn = self.links[name]
        other = self.links["gcs" if name == "service" else "service"]
        while not self._stop.is_set():
            for msg in conn.receive():
                if name == "service":
                    self.from_service.add(msg)
                target = (getattr(msg, "target_system", 0), getattr(msg, "target_component", 0))
                if target == (self.system_id, 1):
                    self._handle_own(name, msg)
                    continue  # addressed to the autopilot only
                other.write(msg.get_msgbuf())  # as received, signature included


class GroundStation(Background):
    """A pymavlink ground station (system 255, component 190) talking to the autopilot's gcs port."""

    def __init__(self, gcs_port: int, key: bytes | None = None) -> None:
        super().__init__(self._receive, self._heartbeat)
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=255, source_component=190)
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=lambda mav, msg_id: True,
                                    initial_timestamp=int((time.time() - 1420070400) * 1e5))
        self.received = Recorder()
        self._send_lock = threading.Lock()

    def release(self) -> None:
        self.conn.close()

    def send(self, msg: object) -> None:
        with self._send_lock:
            self.conn.mav.send(msg)

    def _heartbeat(self) -> None:
        while True:
            self.send(self.conn.mav.heartbeat_encode(6, 8, 0, 0, 4))  # GCS, INVALID autopilot
            if self._stop.wait(0.2):
                return

    def _receive(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.received.add(msg)

    def command_long(self, command: int, params: list[float], target=(1, 100)) -> None:
        self.send(self.conn.mav.command_long_encode(target[0], target[1], command, 0, *params))

    def command_int(self, command: int, p1: float, p2: float, p3: float, p4: float, x: int, y: int, z: float,
                    target=(1, 100)) -> None:
        self.send(self.conn.mav.command_int_encode(target[0], target[1], 0, command, 0, 0, p1, p2, p3, p4, x, y, z))

    def wait_ack(self, command: int, after: int, timeout_s: float = 5.0) -> object | None:
        """The first COMMAND_ACK for `command` beyond the first `after` acks for it; None on timeout."""
        def acks() -> list[Received]:
            return [r for r in self.received.of("COMMAND_ACK") if r.msg.command == command]
        if not self.received.wait_for(lambda: len(acks()) > after, timeout_s):
            return None
        return acks()[after].msg

    def ack_count(self, command: int) -> int:
        return len([r for r in self.received.of("COMMAND_ACK") if r.msg.command == command])


def service_config(service_port: int, overrides: dict | None = None) -> ServiceConfig:
    """A test config: file source (path from overrides), csrt, zenoh off, mavlink to service_port."""
    base: dict = {
        "source": {"kind": "file", "path": "unset", "retry_initial_s": 0.05, "retry_max_s": 0.2},
        "tracker": {"name": "csrt", "range_size_band": 0},  # csrt takes no side bounds
        "mavlink": {"url": f"udpout:127.0.0.1:{service_port}", "heartbeat_timeout_s": 1.0},
        "zenoh": {"enabled": False},
        "logging": {"level": "DEBUG"},
    }
    for section, values in (overrides or {}).items():
        base.setdefault(section, {}).update(values) if isinstance(values, dict) else base.__setitem__(section, values)
    return config_from_mapping(base)


@dataclass
class RunningService:
    """A Service running on a thread; stop() joins it."""

    service: object
    stop_event: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None

    def start(self) -> "RunningService":
        self.thread = threading.Thread(target=self.service.run, args=(self.stop_event,), daemon=True)
        self.thread.start()
        return self

    def stop(self) -> None:
        self.stop_event.set()
        if self.thread is not None:
            self.thread.join(3.0)
            assert not self.thread.is_alive(), "service did not stop within 3 s"


MAV_CMD_REQUEST_MESSAGE = 512
CAMERA_INFORMATION_ID = 259


def camera_handshake(gcs: GroundStation, system_id: int, timeout_s: float = 10.0) -> object:
    """A ground station meeting the camera component, as QGroundControl does: the camera's HEARTBEAT
    (MAV_TYPE_CAMERA, from system `system_id` once learned from the autopilot) arrives through the
    autopilot, CAMERA_INFORMATION is requested (MAV_CMD_REQUEST_MESSAGE, ACCEPTED) and received.
    Returns the CAMERA_INFORMATION message; AssertionError naming the missing step otherwise."""
    def camera_beats() -> list[Received]:
        return [r for r in gcs.received.of("HEARTBEAT")
                if r.msg.get_srcComponent() == 100 and r.msg.get_srcSystem() == system_id]
    assert gcs.received.wait_for(lambda: bool(camera_beats()), timeout_s), \
        f"no HEARTBEAT from camera component {system_id}/100 within {timeout_s} s"
    beat = camera_beats()[-1].msg
    assert (beat.type, beat.autopilot) == (30, 8), "camera heartbeat is not MAV_TYPE_CAMERA / AUTOPILOT_INVALID"
    asked = gcs.ack_count(MAV_CMD_REQUEST_MESSAGE)
    gcs.command_long(MAV_CMD_REQUEST_MESSAGE, [CAMERA_INFORMATION_ID, 0, 0, 0, 0, 0, 0], target=(system_id, 100))
    ack = gcs.wait_ack(MAV_CMD_REQUEST_MESSAGE, asked, timeout_s)
    assert ack is not None and ack.result == 0, f"REQUEST_MESSAGE(CAMERA_INFORMATION) not accepted: {ack}"

    def infos() -> list[Received]:
        return [r for r in gcs.received.of("CAMERA_INFORMATION") if r.msg.get_srcSystem() == system_id]
    assert gcs.received.wait_for(lambda: bool(infos()), timeout_s), "no CAMERA_INFORMATION after ACCEPTED"
    return infos()[-1].msg
