"""Helpers for the tests against real autopilot firmware (no tests here): finding the firmware (skip
outside CI, fail in CI), a synthetic target held off centre published as camera frames over Zenoh (the
test decides when it leaves the view), the daemon as a process on a firmware link, a wire tap that
records what the daemon sends, a ground station, and FirmwareRig: all of them with the firmware as one context.

The firmware itself is started by sim.firmware (ArduPilotSitl, Px4Sih)."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as dialect  # noqa: E402

from sim.daemon import write_config  # noqa: E402
from sim.firmware import euler_deg  # noqa: E402
from sim.ports import free_tcp_port, free_udp_port  # noqa: E402
from tests.helpers import Background  # noqa: E402
from tests.service_peers import Recorder  # noqa: E402
from tests.test_service_sources import scene  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FRAME_SIZE = (320, 240)  # px
TARGET_PX = (250.0, 70.0)  # right of and above the image centre (160, 120): yaw right, pitch up
TRACK_RECTANGLE, STOP_TRACKING, SET_INTERVAL = 2005, 2010, 511


def target_image(visible: bool = True) -> Any:
    """A FRAME_SIZE BGR frame: the checkered target at TARGET_PX on the textured background, or the
    background alone (the target gone)."""
    return scene(FRAME_SIZE, TARGET_PX, 30) if visible else scene(FRAME_SIZE, (-100.0, -100.0), 0)


class FramePump(Background):
    """The camera: publishes target_image(visible) over Zenoh at `fps` (wall clock) on a thread; set
    `visible` False to take the target out of view (the track is then lost)."""

    def __init__(self, zenoh_port: int, prefix: str, fps: float = 20.0) -> None:
        from sim.zenoh_link import SimCamera, ZenohEndpoints

        super().__init__(self._run, join_s=2.0)
        self.camera = SimCamera(ZenohEndpoints(listen=(f"tcp/127.0.0.1:{zenoh_port}",), prefix=prefix))
        self.period = 1.0 / fps
        self.visible = True
        self._images = {True: target_image(True), False: target_image(False)}

    def release(self) -> None:
        self.camera.close()

    def _run(self) -> None:
        frame_id = 0
        while not self._stop.wait(self.period):  # a camera's frame clock, not a synchronisation
            self.camera.publish(self._images[self.visible], frame_id)
            frame_id += 1


def target_rectangle() -> list[float]:
    """TRACK_RECTANGLE params 1-4 (normalised top-left x, y, bottom-right x, y) around the target."""
    x, y = TARGET_PX
    w, h = FRAME_SIZE
    return [(x - 17) / w, (y - 17) / h, (x + 17) / w, (y + 17) / h]


def record(parser: Any, data: bytes, into: Recorder) -> None:
    """Every message `parser` (a robust pymavlink parser) finds in the datagram `data`, into `into`; a datagram
    it chokes on records nothing (the tap forwards it all the same)."""
    try:
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() != "BAD_DATA":
                into.add(msg)
    except Exception:  # noqa: BLE001 - forwarded anyway
        pass


class WireTap(Background):
    """A UDP relay between a firmware link and the daemon, recording what the daemon sends.

    The firmware sends (udpclient) to `firmware_port`; the tap forwards that to the daemon's udpin port
    `daemon_port` and the daemon's answers back to the firmware, each datagram as it came. Every message
    from the daemon is parsed and kept in `from_daemon` (Recorder: message + arrival time), every one to
    it in `to_daemon`."""

    def __init__(self, firmware_port: int, daemon_port: int) -> None:
        super().__init__(self._down, self._up)
        self.firmware_port, self.daemon_port = firmware_port, daemon_port
        self.outer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the firmware
        self.outer.bind(("127.0.0.1", firmware_port))
        self.inner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the daemon
        self.inner.bind(("127.0.0.1", 0))
        for sock in (self.outer, self.inner):
            sock.settimeout(0.1)
        self.firmware_address: tuple[str, int] | None = None
        self.parser = dialect.MAVLink(None)
        self.parser.robust_parsing = True
        self.from_daemon = Recorder()
        self.to_daemon = Recorder()  # what reached the daemon (parsed as it passed)
        self._down_parser = dialect.MAVLink(None)
        self._down_parser.robust_parsing = True

    def release(self) -> None:
        self.outer.close()
        self.inner.close()

    def _down(self) -> None:
        """Firmware -> daemon."""
        while not self._stop.is_set():
            try:
                data, address = self.outer.recvfrom(65536)
            except (socket.timeout, OSError):
                continue
            self.firmware_address = address  # a restarted firmware sends from a new port
            self.inner.sendto(data, ("127.0.0.1", self.daemon_port))
            record(self._down_parser, data, self.to_daemon)

    def _up(self) -> None:
        """Daemon -> firmware, recorded."""
        while not self._stop.is_set():
            try:
                data, _ = self.inner.recvfrom(65536)
            except (socket.timeout, OSError):
                continue
            record(self.parser, data, self.from_daemon)
            if self.firmware_address is not None:
                self.outer.sendto(data, self.firmware_address)

    def sent(self, kind: str, since: float = 0.0) -> list[Any]:
        """Messages of `kind` the daemon sent at or after time.monotonic() `since`."""
        return [r.msg for r in self.from_daemon.of(kind) if r.at >= since]


def terminate(process: subprocess.Popen[bytes], grace_s: float) -> None:
    """SIGTERM a still running `process`, SIGKILL it after grace_s seconds; returns once it is gone."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(grace_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5.0)


class DaemonProcess:
    """`python -m service` with frames from Zenoh (a FramePump listening on zenoh_port) on a MAVLink URL,
    config = config.yaml + overrides; log in
    workdir/service.log. A context manager: SIGTERM on exit (kill after 5 s)."""

    def __init__(self, workdir: Path, zenoh_port: int, prefix: str, mavlink_url: str,
                 overrides: dict[str, Any]) -> None:
        base: dict[str, Any] = {
            "source": {"kind": "zenoh"},
            "zenoh": {"enabled": True, "mode": "peer", "listen": [], "connect": [f"tcp/127.0.0.1:{zenoh_port}"],
                      "multicast_scouting": False, "prefix": prefix},
            "tracker": {"name": "csrt", "range_size_band": 0},  # csrt: fast, takes no side bounds
            "camera": {"point_proposal": False, "rectangle_fit": False},
            "logging": {"level": "DEBUG"},
        }
        for section, values in overrides.items():
            base.setdefault(section, {}).update(values)
        self.workdir = workdir
        self.config_path = workdir / "daemon.yaml"
        self.log_path = workdir / "service.log"
        write_config(self.config_path, base)
        self.mavlink_url = mavlink_url
        self.process: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> "DaemonProcess":
        env = dict(os.environ, MAVLINK20="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "service", "--config", str(self.config_path), "--source", "zenoh",
                 "--mavlink", self.mavlink_url],
                cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.process is not None:
            terminate(self.process, 5.0)

    def log_tail(self, lines: int = 30) -> str:
        """The end of the daemon's log (for failure messages)."""
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


class Station(Background):
    """A pymavlink ground station on a firmware link (the test's view): a receiver thread keeps every
    message in `received` (Recorder), a heartbeat thread sends GCS heartbeats at 1 Hz."""

    def __init__(self, url: str, system: int = 255, component: int = 190) -> None:
        from pymavlink import mavutil

        super().__init__(self._receive, self._beat)
        self.conn = mavutil.mavlink_connection(url, source_system=system, source_component=component)
        self.received = Recorder()
        self._send_lock = threading.Lock()

    def release(self) -> None:
        self.conn.close()

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
            except OSError:
                continue
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.received.add(msg)

    def _beat(self) -> None:
        while True:
            self.send(lambda mav: mav.heartbeat_encode(6, 8, 0, 0, 4))  # GCS, AUTOPILOT_INVALID
            if self._stop.wait(1.0):
                return

    def send(self, build: Callable[[Any], Any]) -> None:
        """Send build(mav) (the pymavlink MAVLink object of this link)."""
        with self._send_lock:
            self.conn.mav.send(build(self.conn.mav))

    def command(self, target: tuple[int, int], command: int, params: list[float], timeout: float = 10.0,
                retry_s: float = 1.5) -> Any:
        """COMMAND_LONG to target, sent again every retry_s with the confirmation field counting up (the
        MAVLink command protocol: a lost command or ack is retransmitted, as QGroundControl does); the first
        COMMAND_ACK from that target (AssertionError on none within timeout s)."""
        since = time.monotonic()
        deadline = since + timeout
        padded = list(params) + [0.0] * (7 - len(params))
        confirmation = 0
        while True:
            self.send(lambda mav: mav.command_long_encode(target[0], target[1], command, confirmation, *padded))
            wait_s = min(retry_s, deadline - time.monotonic())
            ack = self.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command
                            and (m.get_srcSystem(), m.get_srcComponent()) == target, wait_s, since)
            if ack is not None or time.monotonic() >= deadline or confirmation == 255:
                break
            confirmation += 1
        assert ack is not None, f"no COMMAND_ACK for {command} from {target} within {timeout} s ({confirmation + 1} sent)"
        return ack

    def wait(self, predicate: Callable[[Any], bool], timeout: float, since: float = 0.0) -> Any:
        """The first message received at or after `since` meeting `predicate`, or None after `timeout` s."""
        found: list[Any] = []
        cursor = [0]  # items before it were checked already: each wake-up looks at the new ones only

        def check() -> bool:
            items = self.received.items
            for item in items[cursor[0]:]:
                if item.at >= since and predicate(item.msg):
                    found.append(item.msg)
                    return True
            cursor[0] = len(items)
            return False
        self.received.wait_for(check, timeout)
        return found[0] if found else None

    def latest(self, kind: str, source: tuple[int, int] | None = None) -> Any:
        """The last message of `kind` (from `source` when given), or None."""
        items = [r.msg for r in self.received.of(kind)
                 if source is None or (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == source]
        return items[-1] if items else None

    def of(self, kind: str, since: float = 0.0) -> list[tuple[float, Any]]:
        """(arrival time, message) of every `kind` received at or after `since`."""
        return [(r.at, r.msg) for r in self.received.of(kind) if r.at >= since]


class FirmwareRig:
    """Real firmware (sim.firmware.ArduPilotSitl or Px4Sih, its second link for the daemon) + ground station +
    tap + camera frames + daemon, as one context: a subclass's __enter__ enters the firmware, sets `autopilot`
    and `camera_id` ((system, component)), starts `gcs` and then start_daemon()."""

    name = "the firmware"  # in failure messages

    def __init__(self, firmware: Any, tmp_path: Path, overrides: dict[str, Any], prefix: str) -> None:
        self.firmware, self.tmp_path, self.overrides, self.prefix = firmware, tmp_path, overrides, prefix

    def start_daemon(self) -> None:
        """The tap on the firmware's second link, the camera frames, and the daemon behind the tap."""
        daemon_port = free_udp_port()
        self.tap = WireTap(self.firmware.ports[1], daemon_port).start()
        zenoh_port = free_tcp_port()
        self.camera = FramePump(zenoh_port, self.prefix).start()
        self.daemon = DaemonProcess(self.tmp_path, zenoh_port, self.prefix, f"udpin:127.0.0.1:{daemon_port}",
                                    self.overrides).__enter__()

    def __exit__(self, *exc: object) -> None:
        for close in (lambda: self.daemon.__exit__(None, None, None), self.camera.close, self.tap.close,
                      self.gcs.close, self.firmware.close):
            try:
                close()
            except Exception:  # noqa: BLE001 - tear down the rest
                pass

    def diagnostics(self) -> str:
        return f"daemon log:\n{self.daemon.log_tail()}\nfirmware log:\n{self.firmware.log_tail(1500)}"

    def stream_to_gcs(self, msg_id: int, hz: float, timeout: float = 15.0) -> Any:
        """Ask the autopilot for `msg_id` on the ground-station link until it arrives (ArduPilot acknowledges
        but does not act on requests in its first seconds); the first one."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            since = time.monotonic()
            assert self.gcs.command(self.autopilot, SET_INTERVAL, [msg_id, 1e6 / hz]).result == 0
            msg = self.gcs.wait(lambda m: m.get_msgId() == msg_id, 2.0, since)
            if msg is not None:
                return msg
        raise AssertionError(f"{self.name} sent no message {msg_id} within {timeout} s")

    def meet_camera(self, timeout: float = 60.0) -> None:
        """The daemon's camera heartbeat reaches the ground station through the autopilot."""
        beat = self.gcs.wait(lambda m: m.get_type() == "HEARTBEAT"
                             and (m.get_srcSystem(), m.get_srcComponent()) == self.camera_id, timeout)
        assert beat is not None, f"no camera heartbeat routed by {self.name}\n{self.diagnostics()}"

    def select(self, timeout: float = 20.0) -> float:
        """TRACK_RECTANGLE around the target to the camera until ACCEPTED (TEMPORARILY_REJECTED while no
        frame has arrived); the monotonic time of the acceptance."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ack = self.gcs.command(self.camera_id, TRACK_RECTANGLE, target_rectangle() + [0])
            if ack.result == 0:
                return time.monotonic()
            assert ack.result == 1, f"TRACK_RECTANGLE answered {ack.result}"  # 1: TEMPORARILY_REJECTED
            self.gcs.wait(lambda m: False, 0.5)  # a frame's time for the camera to start
        raise AssertionError(f"TRACK_RECTANGLE not accepted within {timeout} s\n{self.diagnostics()}")

    def mount_after(self, seconds: float) -> tuple[float, float]:
        """The mount's reported (pitch, yaw) deg at least `seconds` from now (waits on the status stream)."""
        since = time.monotonic() + seconds
        status = self.gcs.wait(lambda m: m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS", seconds + 5.0, since)
        assert status is not None, "GIMBAL_DEVICE_ATTITUDE_STATUS stopped"
        _, pitch, yaw = euler_deg(status.q)
        return pitch, yaw

    def setpoints(self, since: float = 0.0) -> list[Any]:
        """SET_POSITION_TARGET_LOCAL_NED the daemon sent since `since`."""
        return self.tap.sent("SET_POSITION_TARGET_LOCAL_NED", since)
