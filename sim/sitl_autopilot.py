"""The closed loop's autopilot side on real firmware: ArduCopter SITL or PX4 SIH (sim.firmware) instead of the mock.

The firmware flies its own simulated vehicle in real time. The daemon gets the firmware's companion link (its
mavlink.url, as on a drone); the sim sits on the firmware's ground-station link as a tap: it reads the vehicle's
LOCAL_POSITION_NED, ATTITUDE, HEARTBEAT and the mount's GIMBAL_DEVICE_ATTITUDE_STATUS (the scene is rendered
from them) and relays every datagram between that link and the mavsdk ground station (gcs_port), so the
firmware routes the selection to the camera as it would from a real ground station.

Start-up (`start`): the firmware boots (ArduPilot at `setup_speedup` times real time for its 30-40 s
position-estimate wait, then back to real time), arms and takes off to `altitude_m` (ArduPilot in GUIDED; PX4
auto take-off, then Hold), and the operator points the camera 45 degrees down (as the mock's gimbal starts).
The vehicle's position, heading and altitude then become the scene's origin: scene north is the vehicle's
heading at that moment, so the car starts where the mock's starts, ahead of the camera.

Frames: scene = local NED (LOCAL_POSITION_NED, metres from the EKF origin on the ground) shifted to the
origin and turned by the heading at start; yaw radians clockwise from scene north; gimbal pitch radians in
the earth frame (negative = down), gimbal yaw radians relative to the vehicle's nose (earth-framed reports
are turned into that).

PX4 with guidance: PX4 enters OFFBOARD only on a pilot's request while setpoints stream, and leaves it (its
offboard-loss failsafe, Position mode) when they stop for 1 s. `reengage_offboard` plays that pilot: it asks
for OFFBOARD once a second while not in it (PX4 refuses while nothing streams).
"""
from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402  (after MAVLINK20)

from sim.autopilot import PEER_TIMEOUT_S, euler_to_quaternion, quaternion_to_pitch_yaw  # noqa: E402
from sim.firmware import (ArduPilotSitl, Px4Sih, _claim_instance, command, connect, firmware_missing,  # noqa: E402
                          set_message_interval, wait_message)
from sim.vehicle_model import ARDUCOPTER_MODES, PX4_MAIN, PX4_MODES, VehicleSnapshot, wrap_pi  # noqa: E402

TAP_SYSTEM, TAP_COMPONENT = 250, 190  # the sim's own identity on the ground-station link (an operator's station)
STREAM_HZ = 50.0  # the tap's state streams: the scene follows the firmware to within a frame or so
START_PITCH_DEG = -45.0  # where the operator points the camera before the selection (the mock's start)
# PX4: take-off straight to the scene's altitude (MIS_TAKEOFF_ALT), climbing fast (the test budget); its
# offboard-loss failsafe stays the default (Position mode after 1 s: the vehicle stops there). MNT_RANGE_PITCH
# 180: a gimbal that looks straight down, as ArduPilot's servo gimbal here (PX4's default 90 stops the pitch at
# -45 deg; guidance brings the vehicle to 15 m of ground range from 30 m up, 63 deg down).
PX4_PARAMS = {"MPC_TKO_SPEED": 8.0, "MPC_Z_VEL_MAX_UP": 8.0, "MPC_Z_V_AUTO_UP": 8.0, "MNT_RANGE_PITCH": 180.0}


def firmware_kind(flavour: str) -> str:
    """sim.firmware's kind of a closed-loop flavour: ardupilot -> arducopter, px4 -> px4."""
    if flavour not in ("ardupilot", "px4"):
        raise ValueError(f"flavour must be ardupilot or px4, got {flavour!r}")
    return "arducopter" if flavour == "ardupilot" else "px4"


def firmware_unavailable(flavour: str) -> str | None:
    """Why the firmware of `flavour` cannot run here (sim.firmware.firmware_missing), None when it can."""
    return firmware_missing(firmware_kind(flavour))


def mode_name(flavour: str, custom_mode: int) -> str:
    """Flight-mode name of a HEARTBEAT custom_mode (the mock's names; 'MODE <n>' when unknown)."""
    if flavour == "ardupilot":
        return next((name for name, value in ARDUCOPTER_MODES.items() if value == custom_mode), f"MODE {custom_mode}")
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    named = next((name for name, (m, s) in PX4_MODES.items() if m == main and s == sub), None)
    if named is not None:
        return named
    return next((f"{name}.{sub}" for name, value in PX4_MAIN.items() if value == main), f"MODE {custom_mode}")


@dataclass(frozen=True)
class SceneOrigin:
    """Where the scene's origin is in the firmware's local NED: metres, and the heading (rad) taken as north."""

    north: float
    east: float
    yaw: float

    def to_scene(self, north: float, east: float) -> tuple[float, float]:
        """Local NED (north, east) metres -> scene (north, east) metres."""
        dn, de = north - self.north, east - self.east
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return c * dn + s * de, -s * dn + c * de


def rotation_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """3x3 rotation of aerospace Z-Y-X Euler angles (rad): body axes (forward, right, down) in NED columns."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def camera_direction(q: list[float], flags: int, vehicle_rpy: tuple[float, float, float],
                     mount_in_body_frame: bool) -> tuple[float, float]:
    """The optical axis in the earth frame as (pitch, yaw relative to the vehicle's nose), rad, from a
    GIMBAL_DEVICE_ATTITUDE_STATUS (q [w, x, y, z], flags) and the vehicle's ATTITUDE (roll, pitch, yaw).

    mount_in_body_frame: the report is the mount's angles against the vehicle's body (ArduPilot's servo mount
    does that, whatever its flags say), so the camera's earth attitude is the vehicle's rotation then the
    mount's. Otherwise roll and pitch are earth-referenced and yaw is the vehicle-relative one unless flagged
    earth (the MAVLink message's definition)."""
    roll, pitch, yaw = vehicle_rpy
    if mount_in_body_frame:
        w, x, y, z = q
        m_roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        m_pitch, m_yaw = quaternion_to_pitch_yaw(q)
        forward = (rotation_zyx(roll, pitch, yaw) @ rotation_zyx(m_roll, m_pitch, m_yaw))[:, 0]
        cam_pitch = math.asin(max(-1.0, min(1.0, -float(forward[2]))))
        return cam_pitch, wrap_pi(math.atan2(float(forward[1]), float(forward[0])) - yaw)
    cam_pitch, cam_yaw = quaternion_to_pitch_yaw(q)
    if flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME:
        cam_yaw -= yaw
    return cam_pitch, wrap_pi(cam_yaw)


class SitlAutopilot:
    """ArduCopter SITL / PX4 SIH behind the closed loop: start() / close(), snapshot(), a relay for mavsdk.

    The same surface as sim.autopilot.MockAutopilot where the closed loop touches it; `lockstep` is False (the
    firmware runs on its own clock: `step` and `send_state_now` do nothing)."""

    lockstep = False

    def __init__(self, flavour: str, gcs_port: int, altitude_m: float = 30.0, reengage_offboard: bool = False,
                 setup_speedup: float = 10.0, start_timeout_s: float = 120.0, speedup: float = 1.0) -> None:
        missing = firmware_unavailable(flavour)
        if missing:
            raise FileNotFoundError(missing)
        if not altitude_m >= 5.0:
            raise ValueError(f"altitude_m must be >= 5, got {altitude_m}")
        self.flavour = flavour
        self.altitude_m = altitude_m
        self.reengage_offboard = reengage_offboard and flavour == "px4"
        self.setup_speedup = setup_speedup
        self.speedup = speedup  # the run's simulation speed over real time (ArduPilot after the set-up; PX4 throughout)
        self.start_timeout_s = start_timeout_s
        if flavour == "ardupilot":
            self.firmware: ArduPilotSitl | Px4Sih = ArduPilotSitl(speedup=setup_speedup)
        else:
            self.firmware = Px4Sih(params={**PX4_PARAMS, "MIS_TAKEOFF_ALT": altitude_m}, speed_factor=speedup)
        self.gcs_port = gcs_port
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.events: list[tuple[float, str]] = []  # (wall s since the run's origin, what the firmware said / did)
        self.heartbeats: dict[tuple[int, int], float] = {}  # (sysid, compid) -> monotonic time last heard
        self.origin: SceneOrigin | None = None
        self.custom_mode: int | None = None
        self.mode = "-"
        self.armed = False
        self.local: Any = None  # last LOCAL_POSITION_NED
        self.attitude: Any = None  # last ATTITUDE
        self.gimbal: Any = None  # last GIMBAL_DEVICE_ATTITUDE_STATUS
        self.counts: dict[str, int] = {}
        self._conn: Any = None
        self._sock_gcs: Any = None
        # ground stations heard on gcs_port (address -> monotonic time last heard): the command-line one and the
        # web station share it, as on the mock's ground-station link
        self._gcs_peers: dict[tuple[str, int], float] = {}
        self._codec = mavlink.MAVLink(None, srcSystem=TAP_SYSTEM, srcComponent=TAP_COMPONENT)
        self._codec.robust_parsing = True
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self._last_engage = -math.inf
        self._held_locks: list[Any] = []
        self._boot_ms = 0  # the firmware's clock: the newest time_boot_ms heard

    # ----- identity -----------------------------------------------------------------------------
    @property
    def service_url(self) -> str:
        """The daemon's mavlink.url: the firmware's companion link."""
        return self.firmware.companion_url

    @property
    def system_id(self) -> int:
        return self.firmware.system_id

    # ----- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "SitlAutopilot":
        """Boot the firmware, take off to altitude_m, point the camera down, fix the scene's origin, start the tap."""
        fw = self.firmware
        deadline = time.monotonic() + self.start_timeout_s
        # Held from now on: gcs_port was free when it was picked, and the firmware's boot opens sockets of its
        # own for tens of seconds (a port bound only after the take-off was once taken meanwhile).
        self._sock_gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock_gcs.bind(("127.0.0.1", self.gcs_port))
        self._sock_gcs.setblocking(False)
        conn = self._conn = connect(fw.gcs_url, TAP_SYSTEM, TAP_COMPONENT)
        self._boot(conn)
        fw.arm_takeoff(conn, self.altitude_m, max(10.0, deadline - time.monotonic()))
        if isinstance(fw, ArduPilotSitl) and fw.speedup != self.speedup:
            fw.set_speedup(conn, self.speedup)
        for msg_id in (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_ATTITUDE,
                       mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS):  # arm_takeoff sets its own rates
            set_message_interval(conn, fw.target, msg_id, STREAM_HZ)
        self._point_camera(conn, START_PITCH_DEG, max(10.0, deadline - time.monotonic()))
        # hover: the origin is where the vehicle holds, once the climb has settled
        position = wait_message(conn, "LOCAL_POSITION_NED", 10.0, lambda m: abs(m.vz) < 0.3 and -m.z > 0.9 * self.altitude_m,
                                what="a steady hover")
        attitude = wait_message(conn, "ATTITUDE", 5.0, what="ATTITUDE")
        self.origin = SceneOrigin(position.x, position.y, attitude.yaw)
        self.local, self.attitude = position, attitude
        self._boot_ms = max(position.time_boot_ms, attitude.time_boot_ms)
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"sitl-tap-{self.flavour}", daemon=True)
        self._thread.start()
        return self

    def _boot(self, conn: Any, attempts: int = 3) -> None:
        """Start the firmware and wait for its heartbeat. A firmware that exits at once (seen: ArduPilot's TCP
        port of SERIAL2 taken by an instance someone started without sim.firmware's instance lock) is started
        again under the next free instance number, on the same UDP ports (the daemon's URL is already set)."""
        fw = self.firmware
        for attempt in range(attempts):
            fw.start()
            try:
                fw.wait_heartbeat(conn, 60.0)
                return
            except TimeoutError:
                if fw.running() or attempt == attempts - 1:
                    raise
            fw.stop()
            instance, lock = _claim_instance(fw.kind, fw.instance + 1, 39)
            self._held_locks.append(lock)  # freed in close(), with the instance's own
            fw.instance = instance
            if isinstance(fw, Px4Sih):
                fw.system_id = instance + 1

    def _point_camera(self, conn: Any, pitch_deg: float, timeout_s: float) -> None:
        """The operator points the camera `pitch_deg` down, straight ahead; waits for the mount's report."""
        fw = self.firmware
        if isinstance(fw, Px4Sih):  # PX4 moves the mount only for its primary controller
            command(conn, fw.target, mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                    [TAP_SYSTEM, TAP_COMPONENT, -1, -1, 0, 0, 0])
        deadline = time.monotonic() + timeout_s
        target = math.radians(pitch_deg)
        while True:
            # GIMBAL_MANAGER_SET_ATTITUDE: both firmwares take it (PX4 ignores GIMBAL_MANAGER_SET_PITCHYAW)
            conn.mav.gimbal_manager_set_attitude_send(fw.system_id, fw.component_id, 0, 0,
                                                      euler_to_quaternion(0.0, target, 0.0), math.nan, math.nan, math.nan)
            try:
                wait_message(conn, "GIMBAL_DEVICE_ATTITUDE_STATUS", 1.0,
                             lambda m: abs(quaternion_to_pitch_yaw(m.q)[0] - target) < math.radians(1.0),
                             what="the mount's pitch")
                return
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{fw.kind}: the mount did not reach pitch {pitch_deg} deg; log:\n{fw.log_tail()}")

    def close(self) -> None:
        """Stop the tap and the firmware (by its PID), remove its working directory."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for sock in (self._sock_gcs,):
            if sock is not None:
                sock.close()
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        self.firmware.close()
        for lock in self._held_locks:
            lock.close()

    def __enter__(self) -> "SitlAutopilot":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- the closed loop's surface ------------------------------------------------------------
    def snapshot(self) -> VehicleSnapshot:
        """The vehicle and mount in the scene's frame (see the module doc), from the latest messages."""
        with self.lock:
            assert self.origin is not None and self.local is not None and self.attitude is not None
            lp, yaw = self.local, self.attitude.yaw
            north, east = self.origin.to_scene(lp.x, lp.y)
            c, s = math.cos(self.origin.yaw), math.sin(self.origin.yaw)
            v_north, v_east = c * lp.vx + s * lp.vy, -s * lp.vx + c * lp.vy
            if self.gimbal is not None:
                att = self.attitude
                pitch, gimbal_yaw = camera_direction(list(self.gimbal.q), self.gimbal.flags,
                                                     (att.roll, att.pitch, att.yaw), self.flavour == "ardupilot")
            else:
                pitch, gimbal_yaw = math.radians(START_PITCH_DEG), 0.0
            return VehicleSnapshot(north, east, lp.z, wrap_pi(yaw - self.origin.yaw), pitch, gimbal_yaw,
                                   v_north, v_east, self.mode)

    def firmware_time_s(self) -> float:
        """The firmware's clock (s since its boot) as its latest ATTITUDE / LOCAL_POSITION_NED stamps it."""
        with self.lock:
            return self._boot_ms / 1000.0

    def wait_firmware_time(self, time_s: float, timeout_s: float) -> bool:
        """Wait (wall timeout_s) until the firmware's clock has reached time_s; whether it has."""
        return self.wait_for(lambda: self._boot_ms >= time_s * 1000.0, timeout_s)

    def step(self, dt_s: float) -> None:
        """Nothing: the firmware runs on its own (real-time) clock."""

    def send_state_now(self) -> None:
        """Nothing: the firmware streams on its own clock."""

    def link_is_down(self, name: str) -> bool:
        """No link drops are simulated with firmware."""
        return False

    def drop_link(self, seconds: float, links: tuple[str, ...] = ("service",)) -> None:
        raise ValueError("link drops are simulated by the mock autopilot only")

    def heard_heartbeat(self, component: int) -> bool:
        """Whether a heartbeat from `component` of the autopilot's system came through the firmware."""
        return any(key == (self.firmware.system_id, component) for key in self.heartbeats)

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until predicate() (under the lock) holds or timeout_s wall seconds pass."""
        with self.changed:
            return self.changed.wait_for(predicate, timeout=timeout_s)

    def wait_for_heartbeat(self, component: int, timeout_s: float, link: str = "service",
                           unless: Callable[[], bool] = lambda: False) -> bool:
        """Wait until the firmware relays a heartbeat of `component` (the daemon's camera), or unless() holds."""
        self.wait_for(lambda: unless() or self.heard_heartbeat(component), timeout_s)
        with self.lock:
            return self.heard_heartbeat(component)

    def wake_waiters(self) -> None:
        with self.changed:
            self.changed.notify_all()

    def request_mode(self, mode: str) -> None:
        """The pilot asks for flight mode `mode` (a mock name: GUIDED, OFFBOARD, HOLD ...); the answer comes back
        as an event (COMMAND_ACK), not awaited."""
        if self.flavour == "ardupilot":
            params = [mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDUCOPTER_MODES[mode], 0]
        else:
            main, sub = PX4_MODES[mode]
            params = [mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub]
        self._send(self._codec.command_long_encode(self.firmware.system_id, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                                   *params, 0, 0, 0, 0))

    # ----- the tap ------------------------------------------------------------------------------
    def _send(self, msg: Any) -> None:
        """Send one of the sim's own messages to the firmware on the ground-station link."""
        conn = self._conn
        if conn is None or conn.last_address is None:
            return
        conn.port.sendto(msg.pack(self._codec), conn.last_address)

    def _run(self) -> None:
        fw_sock = self._conn.port
        fw_sock.setblocking(False)
        next_beat = 0.0
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([fw_sock, self._sock_gcs], [], [], 0.1)
            except (OSError, ValueError):
                return
            for sock in ready:
                while True:  # drain: both sockets are non-blocking
                    try:
                        data, addr = sock.recvfrom(65536)
                    except OSError:  # nothing more (BlockingIOError), or closed under us
                        break
                    if sock is fw_sock:
                        self._conn.last_address = addr
                        now = time.monotonic()
                        for peer in [p for p, heard in self._gcs_peers.items() if now - heard > PEER_TIMEOUT_S]:
                            del self._gcs_peers[peer]
                        for peer in self._gcs_peers:
                            try:
                                self._sock_gcs.sendto(data, peer)
                            except OSError:
                                pass  # a ground station gone (ICMP unreachable): the others still get it
                        self._observe(data)
                    else:
                        self._gcs_peers[addr] = time.monotonic()
                        if self._conn.last_address is not None:
                            fw_sock.sendto(data, self._conn.last_address)
            now = time.monotonic()
            if now >= next_beat:  # the operator's station beats at 1 Hz, as ground stations do
                next_beat = now + 1.0
                self._send(self._codec.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
                if self.reengage_offboard and self.mode != "OFFBOARD" and now - self._last_engage >= 1.0:
                    self._last_engage = now
                    self.request_mode("OFFBOARD")

    def _observe(self, data: bytes) -> None:
        try:
            messages = self._codec.parse_buffer(data) or []
        except mavlink.MAVError:
            return
        with self.lock:
            for msg in messages:
                kind = msg.get_type()
                if kind == "BAD_DATA":
                    continue
                self.counts[kind] = self.counts.get(kind, 0) + 1
                source = (msg.get_srcSystem(), msg.get_srcComponent())
                own = source == self.firmware.target
                if kind == "HEARTBEAT":
                    self.heartbeats[source] = time.monotonic()
                    if own:
                        self._on_autopilot_heartbeat(msg)
                elif not own:
                    continue
                elif kind == "LOCAL_POSITION_NED":
                    self.local = msg
                    self._boot_ms = max(self._boot_ms, msg.time_boot_ms)
                elif kind == "ATTITUDE":
                    self.attitude = msg
                    self._boot_ms = max(self._boot_ms, msg.time_boot_ms)
                elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                    self.gimbal = msg
                elif kind == "STATUSTEXT":
                    self._event(f"firmware: {msg.text}")
                elif kind == "COMMAND_ACK" and msg.command == mavlink.MAV_CMD_DO_SET_MODE \
                        and msg.target_system == TAP_SYSTEM:
                    if msg.result != mavlink.MAV_RESULT_ACCEPTED:
                        self._event(f"mode request refused (result {msg.result})")
            self.changed.notify_all()

    def _on_autopilot_heartbeat(self, msg: Any) -> None:
        mode = mode_name(self.flavour, int(msg.custom_mode))
        if mode != self.mode:
            self._event(f"mode {self.mode} -> {mode}")
            self.mode = mode
        self.custom_mode = int(msg.custom_mode)
        self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    def _event(self, text: str) -> None:
        self.events.append((time.monotonic() - self._t0, text))

