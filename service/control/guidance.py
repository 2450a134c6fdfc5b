"""Vehicle guidance (pure): when guidance is allowed, and the body-frame velocity setpoint.

Guidance only runs while the operator has put the vehicle in the mode meant for external
setpoints, as the autopilot's heartbeat reports it: ArduPilot GUIDED (custom_mode 4 on copters,
15 on planes and rovers), PX4 OFFBOARD (main mode 6 in bits 16-23 of custom_mode). The service
never arms and never changes modes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20.ardupilotmega import COPTER_MODE_GUIDED, PLANE_MODE_GUIDED
from pymavlink.dialects.v20.common import (
    MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4, MAV_TYPE_FIXED_WING, MAV_TYPE_FLAPPING_WING,
    MAV_TYPE_GROUND_ROVER, MAV_TYPE_SUBMARINE, MAV_TYPE_SURFACE_BOAT, MAV_TYPE_VTOL_DUOROTOR, MAV_TYPE_VTOL_RESERVED5,
    POSITION_TARGET_TYPEMASK_AX_IGNORE, POSITION_TARGET_TYPEMASK_AY_IGNORE, POSITION_TARGET_TYPEMASK_AZ_IGNORE,
    POSITION_TARGET_TYPEMASK_X_IGNORE, POSITION_TARGET_TYPEMASK_Y_IGNORE, POSITION_TARGET_TYPEMASK_YAW_IGNORE,
    POSITION_TARGET_TYPEMASK_Z_IGNORE,
)

from service.config import GuidanceConfig

PX4_MAIN_MODE_OFFBOARD = 6  # PX4's px4_custom_mode.h, not a MAVLink enum
# MAV_TYPE values flown by ArduPlane / driven by ArduRover (GUIDED = 15 in both: PLANE_MODE_GUIDED, ROVER_MODE_GUIDED);
# the rest are copter-like
FIXED_WING_OR_GROUND_TYPES = {MAV_TYPE_FIXED_WING, MAV_TYPE_GROUND_ROVER, MAV_TYPE_SURFACE_BOAT, MAV_TYPE_SUBMARINE,
                              MAV_TYPE_FLAPPING_WING, *range(MAV_TYPE_VTOL_DUOROTOR, MAV_TYPE_VTOL_RESERVED5 + 1)}
# SET_POSITION_TARGET_LOCAL_NED type_mask: ignore position, acceleration and yaw; use velocity and yaw rate
VELOCITY_YAW_RATE_TYPE_MASK = (POSITION_TARGET_TYPEMASK_X_IGNORE | POSITION_TARGET_TYPEMASK_Y_IGNORE
                               | POSITION_TARGET_TYPEMASK_Z_IGNORE | POSITION_TARGET_TYPEMASK_AX_IGNORE
                               | POSITION_TARGET_TYPEMASK_AY_IGNORE | POSITION_TARGET_TYPEMASK_AZ_IGNORE
                               | POSITION_TARGET_TYPEMASK_YAW_IGNORE)


def px4_main_mode(custom_mode: int) -> int:
    """PX4 custom_mode -> main mode (bits 16-23)."""
    return (custom_mode >> 16) & 0xFF


def guidance_allowed(autopilot: int, vehicle_type: int, custom_mode: int) -> bool:
    """True when the heartbeat (autopilot, type, custom_mode) says GUIDED (ArduPilot) / OFFBOARD (PX4)."""
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        guided = PLANE_MODE_GUIDED if vehicle_type in FIXED_WING_OR_GROUND_TYPES else COPTER_MODE_GUIDED
        return custom_mode == guided
    if autopilot == MAV_AUTOPILOT_PX4:
        return px4_main_mode(custom_mode) == PX4_MAIN_MODE_OFFBOARD
    return False


@dataclass(frozen=True)
class VelocitySetpoint:
    """Body frame (forward, right, down) m/s and yaw rate rad/s (positive = clockwise seen from above)."""

    forward: float = 0.0
    right: float = 0.0
    down: float = 0.0
    yaw_rate: float = 0.0


ZERO_VELOCITY = VelocitySetpoint()


def velocity_setpoint(bearing_rad: float, ground_range_m: float | None, config: GuidanceConfig) -> VelocitySetpoint:
    """Turn towards the target and hold the follow distance.

    bearing_rad: target direction relative to the vehicle's nose (rad, positive = right);
    ground_range_m: horizontal distance to the target (None when it cannot be estimated: then the
    vehicle only turns and does not move).
    """
    if not math.isfinite(bearing_rad):
        raise ValueError(f"bearing must be finite, got {bearing_rad}")
    bearing = math.atan2(math.sin(bearing_rad), math.cos(bearing_rad))  # wrap to [-pi, pi]
    max_yaw = math.radians(config.max_yaw_rate_deg_s)
    yaw_rate = max(-max_yaw, min(max_yaw, config.yaw_gain * bearing))
    forward = 0.0
    if ground_range_m is not None and math.isfinite(ground_range_m):
        # move only when roughly facing the target: scale by cos(bearing), never backwards past 90 deg
        facing = max(0.0, math.cos(bearing))
        speed = config.forward_gain * (ground_range_m - config.follow_distance_m) * facing
        forward = max(-config.max_speed_m_s, min(config.max_speed_m_s, speed))
    return VelocitySetpoint(forward=forward, yaw_rate=yaw_rate)
