"""Mock autopilot (ArduCopter or PX4 flavour) on two loopback UDP links, with MAVLink 2 routing.

Imperative shell around `sim.vehicle_model.VehicleModel`: it owns two UDP sockets, one for the
service (the companion computer) and one for the ground station, parses MAVLink 2 with pymavlink,
hands the messages meant for the autopilot to the model, forwards the others between the links
(as ArduPilot / PX4 routing does), and streams HEARTBEAT, GLOBAL_POSITION_INT, ATTITUDE,
GIMBAL_DEVICE_ATTITUDE_STATUS and GIMBAL_MANAGER_STATUS from the model's state.

Clocks: the model's clock (`model.time_s`, advanced only by `step`) stamps received commands and
measures setpoint timeouts and link drops, so a lockstep closed loop is reproducible; heartbeats and
telemetry streams go out on the wall clock (1 Hz / `stream_hz`) because the peers judge link health
by wall time; a lockstep caller also sends them after every step (`send_state_now`). Each link answers
every peer heard on it in the last PEER_TIMEOUT_S (like a router's UDP server endpoint), so a
command-line and a web ground station can share the ground-station link.

Run alone: `python -m sim.autopilot --flavour px4 --service-port 14555 --gcs-port 14550`.
"""
from __future__ import annotations

import argparse
import collections
import math
import os
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402  (after MAVLINK20)

from sim.vehicle_model import (ARDUCOPTER_MODES, FLAVOURS, PX4_MODES, ReceivedCommand,  # noqa: E402
                               VehicleConfig, VehicleModel, VehicleSnapshot, mount_angles_in_body, wrap_pi)

AUTOPILOT_COMPONENT = 1
LINK_NAMES = ("service", "gcs")
PEER_TIMEOUT_S = 10.0  # a link stops sending to a peer not heard for this long (ground stations beat at 1 Hz)
RECORD_LIMIT = 200_000  # received-message record kept in memory (a ring: a 1 h soak must stay flat)
NAN = float("nan")


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    """Aerospace Z-Y-X Euler angles (rad) -> quaternion [w, x, y, z] (MAVLink order)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


def quaternion_to_pitch_yaw(q: Iterable[float]) -> tuple[float, float]:
    """Quaternion [w, x, y, z] -> (pitch, yaw) radians, Z-Y-X convention."""
    w, x, y, z = q
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return pitch, yaw


def message_target(msg: mavlink.MAVLink_message) -> tuple[int, int] | None:
    """(target_system, target_component) of a targeted message, None for a broadcast-only type."""
    fields = msg.get_fieldnames()
    if "target_system" not in fields:
        return None
    comp = getattr(msg, "target_component", 0) if "target_component" in fields else 0
    return int(msg.target_system), int(comp)


@dataclass
class Link:
    """One UDP endpoint of the autopilot: its socket, its MAVLink codec and the peers heard (address ->
    monotonic time last heard)."""

    name: str
    sock: socket.socket
    codec: mavlink.MAVLink
    peers: dict[tuple[str, int], float] = field(default_factory=dict)
    rx_packets: int = 0
    tx_packets: int = 0
    dropped_packets: int = 0  # both ways (link drops, send errors)
    dropped_incoming: int = 0  # received during a link drop


@dataclass
class AutopilotStats:
    """Counters for assertions: per-type received counts, heartbeats seen per (link, sysid, compid)."""

    received_by_type: collections.Counter = field(default_factory=collections.Counter)
    # (source component, type) -> count; commands as "COMMAND_LONG:<id>" (a lockstep sim waits on these)
    received_by_source: collections.Counter = field(default_factory=collections.Counter)
    heartbeats: dict = field(default_factory=dict)  # (link, sysid, compid) -> wall time of the last one
    forwarded: int = 0


class MockAutopilot:
    """Mock ArduCopter / PX4 on two UDP ports (service link, ground-station link); start() / close()."""

    def __init__(self, config: VehicleConfig, service_port: int, gcs_port: int, host: str = "127.0.0.1",
                 stream_hz: float = 10.0) -> None:
        if not stream_hz > 0:
            raise ValueError(f"stream_hz must be > 0, got {stream_hz}")
        self.model = VehicleModel(config)
        self.flavour = config.flavour
        self.stream_hz = stream_hz
        self.stats = AutopilotStats()
        self.record: collections.deque[ReceivedCommand] = collections.deque(maxlen=RECORD_LIMIT)
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self._drop_until: dict[str, float] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._boot_wall = time.monotonic()
        self.links: dict[str, Link] = {}
        for name, port in (("service", service_port), ("gcs", gcs_port)):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            sock.bind((host, port))
            sock.setblocking(False)
            codec = mavlink.MAVLink(None, srcSystem=config.system_id, srcComponent=AUTOPILOT_COMPONENT)
            codec.robust_parsing = True
            self.links[name] = Link(name, sock, codec)

    # ----- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "MockAutopilot":
        """Start the network thread (receive, route, stream)."""
        self._thread = threading.Thread(target=self._run, name=f"mock-{self.flavour}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close the sockets."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for link in self.links.values():
            link.sock.close()

    def __enter__(self) -> "MockAutopilot":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- caller API ---------------------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """Advance the model's clock and dynamics by dt_s seconds (simulated time)."""
        with self.lock:
            self.model.step(dt_s)
            self.changed.notify_all()

    lockstep = True  # the model steps only when the caller says (sim.sitl_autopilot's firmware cannot)

    def snapshot(self) -> VehicleSnapshot:
        """The vehicle and gimbal state now (sim.vehicle_model.VehicleSnapshot), under the lock."""
        with self.lock:
            return self.model.snapshot()

    @property
    def events(self) -> list[tuple[float, str]]:
        """The model's mode changes and failsafes: (model time s, text)."""
        return self.model.events

    def request_mode(self, mode: str) -> None:
        """The pilot switches flight mode (ValueError where the firmware would refuse, e.g. PX4 OFFBOARD without
        a setpoint stream)."""
        with self.lock:
            self.model.operator_set_mode(mode)

    def drop_link(self, seconds: float, links: Iterable[str] = ("service",)) -> None:
        """Drop all traffic both ways on `links` for `seconds` of the model's clock."""
        with self.lock:
            for name in links:
                if name not in self.links:
                    raise ValueError(f"unknown link {name!r}; expected one of {LINK_NAMES}")
                self._drop_until[name] = self.model.time_s + seconds

    def link_is_down(self, name: str) -> bool:
        """True while `name` is inside a drop window."""
        with self.lock:
            return self.model.time_s < self._drop_until.get(name, -math.inf)

    def commands(self, msg_type: str | None = None, link: str | None = None) -> list[ReceivedCommand]:
        """Snapshot of the record, optionally filtered by message type and link."""
        with self.lock:
            return [c for c in self.record
                    if (msg_type is None or c.msg_type == msg_type) and (link is None or c.link == link)]

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until predicate() (evaluated under the lock) holds or timeout_s wall seconds pass."""
        with self.changed:
            return self.changed.wait_for(predicate, timeout=timeout_s)

    def heard_heartbeat(self, component: int, link: str = "service") -> bool:
        """Whether a heartbeat from `component` has arrived on `link` (call under the lock, or accept a race)."""
        return any(k[0] == link and k[2] == component for k in self.stats.heartbeats)

    def wait_for_heartbeat(self, component: int, timeout_s: float, link: str = "service",
                           unless: Callable[[], bool] = lambda: False) -> bool:
        """Wait until a heartbeat from `component` arrived on `link`, or `unless()` holds (re-checked when the
        condition is notified: whoever makes it true notifies `changed`); True only for the heartbeat."""
        self.wait_for(lambda: unless() or self.heard_heartbeat(component, link), timeout_s)
        with self.lock:
            return self.heard_heartbeat(component, link)

    def wake_waiters(self) -> None:
        """Notify `changed` (e.g. something a wait_for predicate also looks at has happened elsewhere)."""
        with self.changed:
            self.changed.notify_all()

    def send_state_now(self) -> None:
        """Send a heartbeat and the telemetry streams immediately (lockstep: after each step, so peers see
        the new pose and flight mode on the frame after the step, not at the next wall-clock tick)."""
        with self.lock:
            self._send_heartbeat()
            self._send_streams()

    # ----- network thread -----------------------------------------------------------------------
    def _run(self) -> None:
        next_heartbeat = next_stream = 0.0
        socks = {link.sock: link for link in self.links.values()}
        while not self._stop.is_set():
            now = time.monotonic()
            timeout = max(0.0, min(next_heartbeat, next_stream) - now)
            try:
                ready, _, _ = select.select(list(socks), [], [], min(timeout, 0.05))
            except (OSError, ValueError):
                return  # sockets closed under us: shutting down
            for sock in ready:
                self._receive(socks[sock])
            now = time.monotonic()
            with self.lock:
                if now >= next_heartbeat:
                    self._send_heartbeat()
                    next_heartbeat = now + 1.0
                if now >= next_stream:
                    self._send_streams()
                    next_stream = now + 1.0 / self.stream_hz

    def _receive(self, link: Link) -> None:
        while True:
            try:
                data, addr = link.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            with self.lock:
                if self.model.time_s < self._drop_until.get(link.name, -math.inf):
                    link.dropped_packets += 1
                    link.dropped_incoming += 1
                    self.changed.notify_all()
                    continue
                link.peers[addr] = time.monotonic()
                link.rx_packets += 1
                try:
                    messages = link.codec.parse_buffer(data) or []
                except mavlink.MAVError:
                    messages = []
                for msg in messages:
                    if msg.get_type() == "BAD_DATA":
                        continue
                    self._route(link, msg)
                self.changed.notify_all()

    def _route(self, link: Link, msg: mavlink.MAVLink_message) -> None:
        """Handle what is addressed to the autopilot; forward the rest to the other link."""
        own = self.model.config.system_id
        target = message_target(msg)
        if target is None or target[0] == 0:
            for_me, forward = True, True
        elif target[0] == own:
            for_me = target[1] in (0, AUTOPILOT_COMPONENT)
            forward = target[1] != AUTOPILOT_COMPONENT
        else:
            for_me, forward = False, True
        if forward:
            other = self.links["gcs" if link.name == "service" else "service"]
            self._write(other, msg.get_msgbuf())
            self.stats.forwarded += 1
        if for_me:
            self._handle(link, msg)

    def _handle(self, link: Link, msg: mavlink.MAVLink_message) -> None:
        mtype = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        now = self.model.time_s
        self.stats.received_by_type[mtype] += 1
        key = f"{mtype}:{msg.command}" if mtype in ("COMMAND_LONG", "COMMAND_INT") else mtype
        self.stats.received_by_source[(src[1], key)] += 1
        if mtype == "HEARTBEAT":
            self.stats.heartbeats[(link.name, src[0], src[1])] = time.monotonic()
            return
        handler = getattr(self, f"_on_{mtype.lower()}", None)
        outcome = handler(link, msg, src) if handler is not None else "ignored: not handled by the mock"
        fields = {name: getattr(msg, name) for name in msg.get_fieldnames()}
        self.record.append(ReceivedCommand(now, link.name, src[0], src[1], mtype, fields, outcome))

    # ----- handlers (each returns the outcome for the record) -----------------------------------
    def _on_gimbal_manager_set_pitchyaw(self, link: Link, msg, src) -> str:
        if self.flavour == "px4":
            return "ignored: PX4 does not take GIMBAL_MANAGER_SET_PITCHYAW from outside"
        if msg.gimbal_device_id not in (0, 1):
            return f"ignored: no gimbal device {msg.gimbal_device_id}"
        if msg.flags & (mavlink.GIMBAL_MANAGER_FLAGS_RETRACT | mavlink.GIMBAL_MANAGER_FLAGS_NEUTRAL):
            return f"ignored: flags {msg.flags} ask for retract / neutral (ArduPilot then reads no angle or rate)"
        if msg.flags & (mavlink.GIMBAL_MANAGER_FLAGS_YAW_LOCK | mavlink.GIMBAL_MANAGER_FLAGS_YAW_IN_EARTH_FRAME):
            return f"ignored: flags {msg.flags} put yaw in the earth frame (not modelled)"
        angles_nan = math.isnan(msg.pitch) and math.isnan(msg.yaw)
        if angles_nan and math.isfinite(msg.pitch_rate) and math.isfinite(msg.yaw_rate):
            self.model.set_gimbal_rates(msg.pitch_rate, msg.yaw_rate)
            return "applied: rates"
        if math.isfinite(msg.pitch) and math.isfinite(msg.yaw):
            self.model.set_gimbal_angles(msg.pitch, msg.yaw)
            return "applied: angles"
        return "ignored: ArduPilot needs both rates (angles NaN) or both angles"

    def _on_gimbal_manager_set_attitude(self, link: Link, msg, src) -> str:
        if self.flavour == "px4" and tuple(src) != self.model.gimbal_primary:
            return f"ignored: {src} is not the primary gimbal controller {self.model.gimbal_primary}"
        if all(math.isnan(v) for v in msg.q):
            self.model.set_gimbal_rates(msg.angular_velocity_y, msg.angular_velocity_z)
            return "applied: rates"
        if all(math.isfinite(v) for v in msg.q):
            pitch, yaw = quaternion_to_pitch_yaw(msg.q)
            self.model.set_gimbal_angles(pitch, wrap_pi(yaw))
            return "applied: angles"
        return "ignored: partly NaN quaternion"

    def _on_set_position_target_local_ned(self, link: Link, msg, src) -> str:
        return self.model.set_velocity(msg.coordinate_frame, msg.type_mask, msg.vx, msg.vy, msg.vz,
                                       msg.yaw_rate, self.model.time_s)

    def _on_follow_target(self, link: Link, msg, src) -> str:
        if not msg.est_capabilities & 1:
            return "ignored: no position capability"
        north, east = self.model.local_of(msg.lat / 1e7, msg.lon / 1e7)
        return self.model.set_follow_target(north, east, src[0], self.model.time_s)

    def _on_command_long(self, link: Link, msg, src) -> str:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        return self._command(link, msg.command, params, src)

    def _on_command_int(self, link: Link, msg, src) -> str:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z]
        return self._command(link, msg.command, params, src)

    def _command(self, link: Link, command: int, p: list[float], src: tuple[int, int]) -> str:
        result = mavlink.MAV_RESULT_ACCEPTED
        outcome = "applied"
        if command == mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE:
            outcome = self.model.configure_gimbal_manager(p[0], p[1], src)
        elif command == mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            if self.flavour == "px4" and tuple(src) != self.model.gimbal_primary:
                result, outcome = mavlink.MAV_RESULT_DENIED, "denied: not the primary gimbal controller"
            elif math.isnan(p[0]) and math.isnan(p[1]):
                self.model.set_gimbal_rates(math.radians(p[2]), math.radians(p[3]))
            else:
                self.model.set_gimbal_angles(math.radians(p[0]), math.radians(p[1]))
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            # Real firmware accepts it; the service must never send it (tests assert on the record).
            mode = self._mode_name(int(p[1]), int(p[2]), int(p[3]))
            if mode is None:
                result, outcome = mavlink.MAV_RESULT_DENIED, "denied: unknown mode"
            else:
                try:
                    self.model.operator_set_mode(mode)
                except ValueError as exc:
                    result, outcome = mavlink.MAV_RESULT_DENIED, f"denied: {exc}"
        elif command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.model.armed = p[0] == 1
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            outcome = "acknowledged (streams run at fixed rates in the mock)"
        elif command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if int(p[0]) == mavlink.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION:
                self._send(link, self._gimbal_manager_information())
            elif int(p[0]) == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                self._send(link, self._heartbeat())
            else:
                result, outcome = mavlink.MAV_RESULT_UNSUPPORTED, "unsupported message request"
        else:
            result, outcome = mavlink.MAV_RESULT_UNSUPPORTED, "unsupported command"
        self._send(link, link.codec.command_ack_encode(command, result, 0, 0, src[0], src[1]))
        return f"ack {result}: {outcome}"

    def _mode_name(self, base_mode: int, custom: int, sub: int) -> str | None:
        if self.flavour == "ardupilot":
            return next((n for n, v in ARDUCOPTER_MODES.items() if v == custom), None)
        return next((n for n, (m, s) in PX4_MODES.items() if m == custom and s == sub), None)

    # ----- outgoing -----------------------------------------------------------------------------
    def _time_boot_ms(self) -> int:
        return int((time.monotonic() - self._boot_wall) * 1000) & 0xFFFFFFFF

    def _heartbeat(self) -> mavlink.MAVLink_message:
        autopilot = (mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA if self.flavour == "ardupilot"
                     else mavlink.MAV_AUTOPILOT_PX4)
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.model.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if self.model.in_guidance_mode:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, autopilot, base,
                                                 self.model.custom_mode, mavlink.MAV_STATE_ACTIVE, 3)

    def _gimbal_manager_information(self) -> mavlink.MAVLink_message:
        cfg = self.model.config
        caps = (mavlink.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS | mavlink.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
                | mavlink.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_FOLLOW | mavlink.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_FOLLOW)
        return mavlink.MAVLink_gimbal_manager_information_message(
            self._time_boot_ms(), caps, 1, 0.0, 0.0, math.radians(cfg.pitch_limits_deg[0]),
            math.radians(cfg.pitch_limits_deg[1]), math.radians(cfg.gimbal_yaw_min_deg),
            math.radians(cfg.gimbal_yaw_max_deg))

    def _send_heartbeat(self) -> None:
        for link in self.links.values():
            self._send(link, self._heartbeat())

    def _send_streams(self) -> None:
        st, model = self.model.state, self.model
        t = self._time_boot_ms()
        lat, lon = model.lat_lon_of(st.north, st.east)
        alt_rel = -st.down
        hdg = int(round(math.degrees(st.yaw) % 360 * 100)) % 36000
        if self.flavour == "ardupilot":
            # ArduPilot's servo mount: its angles against the vehicle's body, flagged roll / pitch lock and yaw in
            # the vehicle frame (44), as ArduCopter SITL with MNT1_TYPE 1 reports them
            gimbal_q = euler_to_quaternion(*mount_angles_in_body((st.roll, st.pitch, st.yaw), st.gimbal_pitch,
                                                                 st.gimbal_yaw))
            gimbal_flags = (mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                            | mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
        else:
            # PX4 (gimbal manager v2, no device): earth pitch, yaw relative to the nose, flags roll / pitch lock (12)
            gimbal_q = euler_to_quaternion(0.0, st.gimbal_pitch, st.gimbal_yaw)
            gimbal_flags = mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
        gpi = mavlink.MAVLink_global_position_int_message(
            t, int(lat * 1e7), int(lon * 1e7), int((model.config.home_alt_m + alt_rel) * 1000),
            int(alt_rel * 1000), int(st.v_north * 100), int(st.v_east * 100), int(st.v_down * 100), hdg)
        att = mavlink.MAVLink_attitude_message(t, st.roll, st.pitch, st.yaw, 0.0, 0.0, st.yaw_rate)
        gdas = mavlink.MAVLink_gimbal_device_attitude_status_message(
            0, 0, t, gimbal_flags, gimbal_q, 0.0,
            st.gimbal_pitch_rate, st.gimbal_yaw_rate, 0, st.gimbal_yaw, NAN, 1)
        gms = mavlink.MAVLink_gimbal_manager_status_message(
            t, mavlink.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME, 1, model.gimbal_primary[0],
            model.gimbal_primary[1], 0, 0)
        for link in self.links.values():
            for msg in (gpi, att, gdas, gms):
                self._send(link, msg)

    def _send(self, link: Link, msg: mavlink.MAVLink_message) -> None:
        """Pack with the link's own sequence numbering and send to its peers."""
        self._write(link, msg.pack(link.codec))
        link.codec.seq = (link.codec.seq + 1) % 256

    def _write(self, link: Link, data: bytes) -> None:
        now = time.monotonic()
        for addr in [a for a, heard in link.peers.items() if now - heard > PEER_TIMEOUT_S]:
            del link.peers[addr]
        if not link.peers:
            return  # like udpin: nothing heard yet, nobody to send to
        if self.model.time_s < self._drop_until.get(link.name, -math.inf):
            link.dropped_packets += 1
            return
        for addr in link.peers:
            try:
                link.sock.sendto(data, addr)
                link.tx_packets += 1
            except OSError:
                link.dropped_packets += 1  # peer gone (ICMP unreachable): keep running like firmware


def run_realtime(autopilot: MockAutopilot, stop: threading.Event, rate_hz: float = 50.0) -> None:
    """Step the model on the wall clock until `stop` is set (stand-alone and real-time replay runs)."""
    period = 1.0 / rate_hz
    last = time.monotonic()
    while not stop.wait(period):
        now = time.monotonic()
        autopilot.step(max(now - last, 1e-6))
        last = now


def main(argv: list[str] | None = None) -> int:
    """Stand-alone mock autopilot on the wall clock."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flavour", choices=FLAVOURS, default="ardupilot")
    parser.add_argument("--service-port", type=int, default=14555)
    parser.add_argument("--gcs-port", type=int, default=14550)
    parser.add_argument("--system-id", type=int, default=1)
    parser.add_argument("--mode", default="", help="start flight mode (default GUIDED / OFFBOARD)")
    args = parser.parse_args(argv)
    config = VehicleConfig(flavour=args.flavour, system_id=args.system_id, start_mode=args.mode)
    stop = threading.Event()
    with MockAutopilot(config, args.service_port, args.gcs_port) as ap:
        print(f"mock {args.flavour} autopilot: service link udp 127.0.0.1:{args.service_port}, "
              f"ground station udp 127.0.0.1:{args.gcs_port}; Ctrl-C to stop", flush=True)
        try:
            run_realtime(ap, stop)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
