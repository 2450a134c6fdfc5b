"""Ground-station CLI on mavsdk 4.x: list cameras, select a target (point / rectangle), print the
tracking status, stop tracking. An independent MAVLink implementation (MAVSDK's C++ core), so using
it against the service proves interoperability with a stack we did not write.

mavsdk's Camera plugin covers discovery (camera_list) and the three commands (track_point,
track_rectangle, track_stop). It has no tracking-status subscription and no way to set a message
interval, so those two use mavsdk's MavlinkDirect plugin (still mavsdk, not pymavlink):
MAV_CMD_SET_MESSAGE_INTERVAL for CAMERA_TRACKING_IMAGE_STATUS (275) through `send_command`, and a
`subscribe_message("CAMERA_TRACKING_IMAGE_STATUS")`. mavsdk's own log lines go to Python logging
(logger "mavsdk", DEBUG) instead of the console.

    python -m sim.gcs --url udpout://127.0.0.1:14550 list
    python -m sim.gcs --url udpout://127.0.0.1:14550 rect 0.45 0.40 0.55 0.60 --watch 5
    python -m sim.gcs --url udpout://127.0.0.1:14550 status --watch 5
    python -m sim.gcs --url udpout://127.0.0.1:14550 point 0.5 0.5 --radius 0.03
    python -m sim.gcs --url udpout://127.0.0.1:14550 stop
"""
from __future__ import annotations

import argparse
import collections
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

from mavsdk import ComponentType, Configuration, ConnectionResult, LogLevel, Mavsdk, log_subscribe
from mavsdk.plugins.camera import Camera
from mavsdk.plugins.camera.camera import CameraError, CameraResult, Information
from mavsdk.plugins.mavlink_direct.mavlink_direct import MavlinkDirect, MavlinkMessage

log = logging.getLogger("sim.gcs")
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
    """A mavsdk ground station on one connection URL (e.g. udpout://127.0.0.1:14550)."""

    def __init__(self, url: str, discovery_timeout_s: float = 10.0) -> None:
        route_mavsdk_logs()
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        result = self.mavsdk.add_any_connection(url)
        if ConnectionResult(int(result)) != ConnectionResult.SUCCESS:
            self.mavsdk.destroy()
            raise ConnectionError(f"mavsdk cannot open {url}: {result}")
        system = self.mavsdk.first_autopilot(discovery_timeout_s)
        if system is None:
            self.mavsdk.destroy()
            raise TimeoutError(f"no autopilot seen on {url} within {discovery_timeout_s} s")
        self.system = system
        self.camera = Camera(system)
        self.direct = MavlinkDirect(system)
        self.statuses: collections.deque[TrackingStatus] = collections.deque(maxlen=1000)
        self._status_count = 0
        self._status_cond = threading.Condition()
        self._status_handle = self.direct.subscribe_message("CAMERA_TRACKING_IMAGE_STATUS", self._on_status)

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
                    raise TimeoutError(f"no camera discovered within {timeout_s} s")
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
        """Ask the camera for message 275 every interval_s (<= 0: off); returns the MAV_RESULT."""
        interval_us = -1 if interval_s <= 0 else int(interval_s * 1e6)
        command = MavlinkMessage(
            message_name="COMMAND_LONG", system_id=0, component_id=0,
            target_system_id=self.system.get_system_id(), target_component_id=component_id,
            fields_json=json.dumps({"target_system": self.system.get_system_id(),
                                    "target_component": component_id,
                                    "command": MAV_CMD_SET_MESSAGE_INTERVAL, "confirmation": 0,
                                    "param1": CAMERA_TRACKING_IMAGE_STATUS, "param2": interval_us,
                                    "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}))
        ack = self.direct.send_command(command)
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


def format_status(status: TrackingStatus) -> str:
    """One line: status name, mode, rectangle."""
    x0, y0, x1, y1 = status.rectangle
    return (f"camera {status.camera_component}: {status.status_name:8s} mode {status.mode} "
            f"rect ({x0:.3f}, {y0:.3f}) - ({x1:.3f}, {y1:.3f})")


def main(argv: list[str] | None = None) -> int:
    """Command line."""
    parser = argparse.ArgumentParser(description="mavsdk ground station: camera tracking commands and status")
    parser.add_argument("--url", default="udpout://127.0.0.1:14550", help="mavsdk connection URL")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--camera", type=int, default=None, help="camera component id (default: first found)")
    common.add_argument("--watch", type=float, default=0.0, help="print tracking status for this many seconds")
    common.add_argument("--interval", type=float, default=0.5, help="status interval to request, seconds")
    parser.add_argument("--timeout", type=float, default=10.0)
    sub = parser.add_subparsers(dest="action", required=True)
    sub.add_parser("list", parents=[common])
    point = sub.add_parser("point", parents=[common])
    point.add_argument("x", type=float)
    point.add_argument("y", type=float)
    point.add_argument("--radius", type=float, default=0.03)
    rect = sub.add_parser("rect", parents=[common])
    for name in ("top_x", "top_y", "bottom_x", "bottom_y"):
        rect.add_argument(name, type=float)
    sub.add_parser("stop", parents=[common])
    sub.add_parser("status", parents=[common])
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    with GroundStation(args.url, args.timeout) as gcs:
        info = gcs.wait_for_camera(args.timeout, args.camera)
        comp = info.component_id
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
            print(f"rejected: {exc}")
            return 1
        if args.watch > 0 or args.action == "status":
            gcs.set_status_interval(comp, args.interval)
            end = time.monotonic() + (args.watch or 3.0)
            while time.monotonic() < end:
                status = gcs.wait_status(lambda s: True, max(end - time.monotonic(), 0.01))
                if status is not None:
                    print(format_status(status), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
