"""What the service knows about the autopilot and vehicle, as heard on the link (pure updates).

`observe` folds one received message into an immutable AutopilotView. Times are time.monotonic()
seconds; positions degrees / metres; angles radians (NED).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from pymavlink.dialects.v20.common import MAV_AUTOPILOT_INVALID, MAV_COMP_ID_AUTOPILOT1

from service.control.geo import GimbalAttitude, VehiclePose, gimbal_attitude_from_status, heading_rate


@dataclass(frozen=True)
class AutopilotView:
    """Latest autopilot facts; None = never heard."""

    system_id: int | None = None
    autopilot: int | None = None  # MAV_AUTOPILOT of its heartbeat
    vehicle_type: int | None = None  # MAV_TYPE
    custom_mode: int | None = None
    last_heartbeat_s: float | None = None
    position: tuple[float, float, float, float] | None = None  # lat deg, lon deg, alt AMSL m, height above home m
    attitude: tuple[float, float, float] | None = None  # roll, pitch, yaw rad
    heading_rate: float | None = None  # the heading's rate (rad/s, + = clockwise from above) from ATTITUDE's body rates
    attitude_heard_s: float | None = None  # when the last ATTITUDE arrived
    gimbal: GimbalAttitude | None = None
    gimbal_primary: tuple[int, int] | None = None  # (sysid, compid) in control per GIMBAL_MANAGER_STATUS

    def alive(self, now_s: float, timeout_s: float) -> bool:
        """Heartbeat heard within timeout_s."""
        return self.last_heartbeat_s is not None and now_s - self.last_heartbeat_s <= timeout_s

    def fresh_heading_rate(self, now_s: float) -> float | None:
        """The vehicle's heading rate (rad/s, + = clockwise from above), None when ATTITUDE has not been heard within
        stream_late_s of its wanted rate: a stale rate would turn the camera on its own."""
        if self.heading_rate is None or self.attitude_heard_s is None \
                or now_s - self.attitude_heard_s > stream_late_s(WANTED_STREAMS_HZ[ATTITUDE_ID]):
            return None
        return self.heading_rate

    def pose(self) -> VehiclePose | None:
        """Vehicle pose when both position and attitude have been heard."""
        if self.position is None or self.attitude is None:
            return None
        lat, lon, alt, height = self.position
        return VehiclePose(lat, lon, alt, height, *self.attitude)


def is_autopilot_heartbeat(source_component: int, autopilot: int) -> bool:
    """A heartbeat from a flight controller (component 1, a real autopilot type)."""
    return source_component == MAV_COMP_ID_AUTOPILOT1 and autopilot != MAV_AUTOPILOT_INVALID


def observe(view: AutopilotView, msg: object, now_s: float, expected_system: int | None) -> AutopilotView:
    """Fold one pymavlink message into the view; messages from other systems than the autopilot's are ignored."""
    kind = msg.get_type()  # type: ignore[attr-defined]
    source_system = msg.get_srcSystem()  # type: ignore[attr-defined]
    source_component = msg.get_srcComponent()  # type: ignore[attr-defined]
    if kind == "HEARTBEAT":
        if not is_autopilot_heartbeat(source_component, msg.autopilot):  # type: ignore[attr-defined]
            return view
        if expected_system is not None and source_system != expected_system:
            return view
        return replace(view, system_id=source_system, autopilot=msg.autopilot, vehicle_type=msg.type,  # type: ignore[attr-defined]
                       custom_mode=msg.custom_mode, last_heartbeat_s=now_s)  # type: ignore[attr-defined]
    if view.system_id is None or source_system != view.system_id:
        return view
    # A corrupt or made-up pose is ignored, the last good one kept: NaN / infinite angles from the autopilot's
    # system reached the loop's geometry and stopped the operator's track (bench/fuzz.py, event=step_failed).
    if kind == "GLOBAL_POSITION_INT":
        lat, lon = msg.lat / 1e7, msg.lon / 1e7  # type: ignore[attr-defined]
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return view
        return replace(view, position=(lat, lon, msg.alt / 1000.0, msg.relative_alt / 1000.0))  # type: ignore[attr-defined]
    if kind == "ATTITUDE":
        angles = (msg.roll, msg.pitch, msg.yaw)  # type: ignore[attr-defined]
        if not all(math.isfinite(a) for a in angles):
            return view
        rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)  # type: ignore[attr-defined]
        rate = heading_rate(angles[0], angles[1], rates[1], rates[2]) if all(map(math.isfinite, rates)) else None
        return replace(view, attitude=angles, heading_rate=rate, attitude_heard_s=now_s)
    if kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
        q = tuple(msg.q)  # type: ignore[attr-defined]
        if not all(math.isfinite(v) for v in q):
            return view
        try:
            return replace(view, gimbal=gimbal_attitude_from_status(q, msg.flags))  # type: ignore[attr-defined,arg-type]
        except ValueError:
            return view
    if kind == "GIMBAL_MANAGER_STATUS":
        return replace(view, gimbal_primary=(msg.primary_control_sysid, msg.primary_control_compid))  # type: ignore[attr-defined]
    return view


# The autopilot messages the service uses, and the rate it asks for each (Hz). ArduPilot sends nothing
# but heartbeats on a port whose SRn_ stream rates are 0 (its defaults on SERIAL1 / SERIAL2, where a
# companion computer sits) until someone asks with MAV_CMD_SET_MESSAGE_INTERVAL on that port, and a
# reboot forgets what was asked; PX4's onboard link sends GIMBAL_MANAGER_STATUS about every 2-3 s, too
# slow to see a ground station take gimbal control. ATTITUDE 30, GLOBAL_POSITION_INT 33,
# GIMBAL_MANAGER_STATUS 281, GIMBAL_DEVICE_ATTITUDE_STATUS 285.
ATTITUDE_ID = 30
WANTED_STREAMS_HZ = {ATTITUDE_ID: 10.0, 33: 5.0, 281: 5.0, 285: 10.0}
STREAM_RETRY_S = 3.0  # at most one request per message per this many seconds


def stream_late_s(rate_hz: float) -> float:
    """A wanted message not heard for this long (s) arrives too slowly or not at: three periods, >= 0.6 s."""
    return max(0.6, 3.0 / rate_hz)


def streams_to_request(heard_s: dict[int, float], asked_s: dict[int, float], now_s: float) -> list[int]:
    """Ids of WANTED_STREAMS_HZ to ask the autopilot for: not heard (heard_s: id -> last arrival,
    time.monotonic() s) within stream_late_s of its rate, and not asked for (asked_s, same clock) within
    STREAM_RETRY_S. Only what is missing or slow is asked for: on a link shared with a ground station
    (one autopilot port behind a router) a request sets the rate for both."""
    return [msg_id for msg_id, hz in WANTED_STREAMS_HZ.items()
            if now_s - heard_s.get(msg_id, -math.inf) > stream_late_s(hz)
            and now_s - asked_s.get(msg_id, -math.inf) > STREAM_RETRY_S]
