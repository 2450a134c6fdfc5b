"""Ground-station CLI on mavsdk 4.x (MAVSDK's C++ core: a MAVLink stack we did not write, so it proves the
service interoperates): list cameras, select a target, print the tracking status (275, through mavsdk's
MavlinkDirect plugin: the Camera plugin has none), stop. With or without an autopilot on the link; no link
or no camera: a one-line error, exit status 2.

    jsar-gcs --url udpout://127.0.0.1:14550 list          # or python -m gcs.cli ...
    jsar-gcs --url udpout://127.0.0.1:14550 rect 0.45 0.40 0.55 0.60 --watch 5
    jsar-gcs --url udpout://127.0.0.1:14550 point 0.5 0.5 --radius 0.03
    jsar-gcs --url udpout://127.0.0.1:14550 status --watch 5
    jsar-gcs --url udpout://127.0.0.1:14550 stop
    jsar-gcs --url udpin://0.0.0.0:14550 list             # bench: the daemon sends to this port
"""
from __future__ import annotations

import argparse
import collections
import json
import logging
import math
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

from mavsdk import ComponentType, Configuration, ConnectionResult, LogLevel, Mavsdk, log_subscribe
from mavsdk.system import System
from mavsdk.plugins.camera import Camera
from mavsdk.plugins.camera.camera import CameraError, CameraResult, Information
from mavsdk.plugins.mavlink_direct.mavlink_direct import MavlinkDirect, MavlinkDirectError, MavlinkMessage

log = logging.getLogger("gcs.cli")
mavsdk_log = logging.getLogger("mavsdk")

CAMERA_TRACKING_IMAGE_STATUS = 275
MAV_CMD_SET_MESSAGE_INTERVAL = 511
STATUS_NAMES = {0: "IDLE", 1: "ACTIVE", 2: "ERROR", 4: "MTI", 8: "COASTING"}
_LEVELS = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.DEBUG, LogLevel.WARN: logging.INFO,
           LogLevel.ERROR: logging.WARNING}


def route_mavsdk_logs() -> None:
    """Send mavsdk's native log output to the 'mavsdk' Python logger (and not to the console)."""
    def handler(level: LogLevel, message: str, file: str | None, line: int) -> bool:
        mavsdk_log.log(_LEVELS.get(level, logging.INFO), "%s", message)
        return True  # True: suppress mavsdk's own coloured console output
    log_subscribe(handler)


@dataclass(frozen=True)
class TrackingStatus:
    """One CAMERA_TRACKING_IMAGE_STATUS: status flags, mode, normalised rectangle (NaN when unknown)."""

    camera_component: int
    status: int
    mode: int
    rectangle: tuple[float, float, float, float]  # top-left x, y, bottom-right x, y (0..1)
    received_s: float

    @property
    def status_name(self) -> str:
        return STATUS_NAMES.get(self.status, str(self.status))

    @staticmethod
    def from_message(message: MavlinkMessage, received_s: float) -> "TrackingStatus":
        """Parse mavsdk's JSON rendering of message 275 (missing / null floats become NaN)."""
        fields = json.loads(message.fields_json)

        def number(name: str) -> float:
            value = fields.get(name)
            return math.nan if value is None else float(value)
        rect = (number("rec_top_x"), number("rec_top_y"), number("rec_bottom_x"), number("rec_bottom_y"))
        return TrackingStatus(message.component_id, int(fields.get("tracking_status", 0)),
                              int(fields.get("tracking_mode", 0)), rect, received_s)


class GroundStation:
    """A mavsdk ground station on one connection URL (e.g. udpout://127.0.0.1:14550), bound to the first
    system that carries a camera (or to system_id): an autopilot with its cameras, or a camera alone."""

    def __init__(self, url: str, discovery_timeout_s: float = 10.0, system_id: int | None = None) -> None:
        route_mavsdk_logs()
        self.url = url
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            result = self.mavsdk.add_any_connection(url)
            if ConnectionResult(int(result)) != ConnectionResult.SUCCESS:
                raise ConnectionError(f"mavsdk cannot open {url}: {ConnectionResult(int(result)).name}")
            self.system = self._wait_for_camera_system(discovery_timeout_s, system_id)
        except BaseException:
            self.mavsdk.destroy()
            raise
        self.camera = Camera(self.system)
        self.direct = MavlinkDirect(self.system)
        self.statuses: collections.deque[TrackingStatus] = collections.deque(maxlen=1000)
        self._status_count = 0
        self._status_cond = threading.Condition()
        self._status_handle = self.direct.subscribe_message("CAMERA_TRACKING_IMAGE_STATUS", self._on_status)

    def _wait_for_camera_system(self, timeout_s: float, system_id: int | None) -> System:
        """The first system (or system_id) that has a camera component; TimeoutError naming what was
        heard (nothing at all, or systems without a camera) otherwise."""
        changed = threading.Event()
        handle = self.mavsdk.subscribe_on_new_system(lambda _user_data: changed.set())
        deadline = time.monotonic() + timeout_s
        heard: dict[int, list[int]] = {}
        try:
            while True:
                for system in self.mavsdk.get_systems():
                    sysid = system.get_system_id()
                    heard[sysid] = system.component_ids()
                    if (system_id is None or sysid == system_id) and system.has_camera():
                        return system
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(discovery_failure(self.url, timeout_s, system_id, heard))
                changed.wait(min(remaining, 0.25))  # woken by a new system; re-polled for new components
                changed.clear()
        finally:
            self.mavsdk.unsubscribe_on_new_system(handle)

    def _on_status(self, message: MavlinkMessage, _user_data: object) -> None:
        status = TrackingStatus.from_message(message, time.monotonic())
        with self._status_cond:
            self.statuses.append(status)
            self._status_count += 1
            self._status_cond.notify_all()

    # ----- discovery ----------------------------------------------------------------------------
    def cameras(self) -> list[Information]:
        """Cameras mavsdk has discovered (after their CAMERA_INFORMATION)."""
        return list(self.camera.camera_list().cameras)

    def wait_for_camera(self, timeout_s: float, component_id: int | None = None) -> Information:
        """The first discovered camera (or the one with component_id); TimeoutError otherwise."""
        deadline = time.monotonic() + timeout_s
        found = threading.Event()

        def on_list(camera_list: object, _user_data: object) -> None:
            found.set()
        handle = self.camera.subscribe_camera_list(on_list)
        try:
            while True:
                for info in self.cameras():
                    if component_id is None or info.component_id == component_id:
                        return info
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    found_ids = [info.component_id for info in self.cameras()]
                    wanted = "no camera" if component_id is None else f"no camera component {component_id}"
                    raise TimeoutError(f"{wanted} announced (CAMERA_INFORMATION) by system "
                                       f"{self.system.get_system_id()} within {timeout_s:g} s"
                                       f"{f'; cameras: {found_ids}' if found_ids else ''}")
                found.wait(min(remaining, 0.5))  # woken by the list callback; re-poll as a fallback
                found.clear()
        finally:
            self.camera.unsubscribe_camera_list(handle)

    # ----- commands -----------------------------------------------------------------------------
    def track_point(self, component_id: int, x: float, y: float, radius: float) -> CameraResult:
        """MAV_CMD_CAMERA_TRACK_POINT (normalised 0..1); raises CameraError unless accepted."""
        return self.camera.track_point(component_id, x, y, radius)

    def track_rectangle(self, component_id: int, top_x: float, top_y: float, bottom_x: float,
                        bottom_y: float) -> CameraResult:
        """MAV_CMD_CAMERA_TRACK_RECTANGLE (normalised 0..1); raises CameraError unless accepted."""
        return self.camera.track_rectangle(component_id, top_x, top_y, bottom_x, bottom_y)

    def track_stop(self, component_id: int) -> CameraResult:
        """MAV_CMD_CAMERA_STOP_TRACKING; raises CameraError unless accepted."""
        return self.camera.track_stop(component_id)

    def set_status_interval(self, component_id: int, interval_s: float) -> int:
        """Ask the camera for message 275 every interval_s (<= 0: off); returns the MAV_RESULT.
        ConnectionError when no acknowledgement arrives."""
        interval_us = -1 if interval_s <= 0 else int(interval_s * 1e6)
        command = MavlinkMessage(
            message_name="COMMAND_LONG", system_id=0, component_id=0,
            target_system_id=self.system.get_system_id(), target_component_id=component_id,
            fields_json=json.dumps({"target_system": self.system.get_system_id(),
                                    "target_component": component_id,
                                    "command": MAV_CMD_SET_MESSAGE_INTERVAL, "confirmation": 0,
                                    "param1": CAMERA_TRACKING_IMAGE_STATUS, "param2": interval_us,
                                    "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}))
        try:
            ack = self.direct.send_command(command)
        except MavlinkDirectError as exc:  # no final COMMAND_ACK (retransmitted by mavsdk, then given up)
            raise ConnectionError(f"camera {component_id} of system {self.system.get_system_id()} did not "
                                  f"acknowledge SET_MESSAGE_INTERVAL: {exc.result.name}") from exc
        return int(json.loads(ack.fields_json).get("result", -1))

    def wait_status(self, predicate: Callable[[TrackingStatus], bool], timeout_s: float) -> TrackingStatus | None:
        """The first status received after this call that satisfies predicate, None on timeout."""
        with self._status_cond:
            start = self._status_count
            found: list[TrackingStatus] = []

            def match() -> bool:
                new = min(self._status_count - start, len(self.statuses))
                for status in list(self.statuses)[len(self.statuses) - new:]:
                    if predicate(status):
                        found.append(status)
                        return True
                return False
            return found[0] if self._status_cond.wait_for(match, timeout=timeout_s) else None

    def close(self) -> None:
        """Unsubscribe and release the mavsdk instance."""
        self.direct.unsubscribe_message(self._status_handle)
        self.mavsdk.destroy()

    def __enter__(self) -> "GroundStation":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def discovery_failure(url: str, timeout_s: float, system_id: int | None, heard: dict[int, list[int]]) -> str:
    """The message for a link on which no (matching) system with a camera appeared: what was heard."""
    if not heard:
        return (f"no MAVLink system heard on {url} within {timeout_s:g} s (udpin:// listens for a sender, "
                f"udpout:// sends first to a listener: check the URL and that the camera or autopilot is up)")
    seen = ", ".join(f"system {sysid} (components {', '.join(map(str, comps)) or 'none yet'})"
                     for sysid, comps in sorted(heard.items()))
    wanted = "a camera component (100-105)" if system_id is None else f"system {system_id} with a camera"
    return f"no {wanted} on {url} within {timeout_s:g} s; heard: {seen}"


def format_status(status: TrackingStatus) -> str:
    """One line: status name, mode, rectangle."""
    x0, y0, x1, y1 = status.rectangle
    return (f"camera {status.camera_component}: {status.status_name:8s} mode {status.mode} "
            f"rect ({x0:.3f}, {y0:.3f}) - ({x1:.3f}, {y1:.3f})")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    parser = argparse.ArgumentParser(prog="jsar-gcs",
                                     description="mavsdk ground station: camera tracking commands and status")
    parser.add_argument("--url", default="udpout://127.0.0.1:14550",
                        help="mavsdk connection URL: udpout://HOST:PORT sends to a listener (an autopilot's "
                             "ground-station port), udpin://HOST:PORT listens, tcpout://, serial:///dev/ttyX:BAUD")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the camera")
    parser.add_argument("--system", type=int, default=None,
                        help="MAVLink system id of the drone (default: the first system with a camera)")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--camera", type=int, default=None, help="camera component id (default: first found)")
    common.add_argument("--watch", type=float, default=0.0, help="print tracking status for this many seconds")
    common.add_argument("--interval", type=float, default=0.5, help="status interval to request, seconds")
    sub = parser.add_subparsers(dest="action", required=True)
    sub.add_parser("list", parents=[common], help="list the cameras")
    point = sub.add_parser("point", parents=[common], help="MAV_CMD_CAMERA_TRACK_POINT (normalised 0..1)")
    point.add_argument("x", type=float)
    point.add_argument("y", type=float)
    point.add_argument("--radius", type=float, default=0.03, help="fraction of the image width")
    rect = sub.add_parser("rect", parents=[common], help="MAV_CMD_CAMERA_TRACK_RECTANGLE (normalised 0..1)")
    for name in ("top_x", "top_y", "bottom_x", "bottom_y"):
        rect.add_argument(name, type=float)
    sub.add_parser("stop", parents=[common], help="MAV_CMD_CAMERA_STOP_TRACKING")
    sub.add_parser("status", parents=[common], help="print CAMERA_TRACKING_IMAGE_STATUS (275) for --watch s (3 s)")
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        parser.error(f"--timeout must be > 0, got {args.timeout}")
    return args


def run(args: argparse.Namespace) -> int:
    """Carry out one subcommand; exit status 0 done, 1 refused by the camera."""
    with GroundStation(args.url, args.timeout, args.system) as gcs:
        info = gcs.wait_for_camera(args.timeout, args.camera)
        comp = info.component_id
        print(f"system {gcs.system.get_system_id()}"
              f"{'' if gcs.system.has_autopilot() else ' (camera only, no autopilot heard)'}, "
              f"camera component {comp}", flush=True)
        if args.action == "list":
            for cam in gcs.cameras():
                print(f"camera component {cam.component_id}: {cam.vendor_name} {cam.model_name} "
                      f"{cam.horizontal_resolution_px}x{cam.vertical_resolution_px}")
        try:
            if args.action == "point":
                print("track_point:", gcs.track_point(comp, args.x, args.y, args.radius).name)
            elif args.action == "rect":
                print("track_rectangle:", gcs.track_rectangle(comp, args.top_x, args.top_y, args.bottom_x,
                                                              args.bottom_y).name)
            elif args.action == "stop":
                print("track_stop:", gcs.track_stop(comp).name)
        except CameraError as exc:
            print(f"rejected: {exc.origin} answered {exc.result.name}", file=sys.stderr)
            return 1
        if args.watch > 0 or args.action == "status":
            result = gcs.set_status_interval(comp, args.interval)
            if result != 0:
                print(f"rejected: the status interval request answered MAV_RESULT {result}", file=sys.stderr)
                return 1
            end = time.monotonic() + (args.watch or 3.0)
            while time.monotonic() < end:
                status = gcs.wait_status(lambda s: True, max(end - time.monotonic(), 0.01))
                if status is not None:
                    print(format_status(status), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command line: exit status 0 done, 1 refused by the camera, 2 no camera / link error."""
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except (ConnectionError, TimeoutError) as exc:
        print(f"jsar-gcs: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
