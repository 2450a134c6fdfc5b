"""Target geolocation (pure): camera ray through the box centre, intersected with flat ground.

Frames: NED (north, east, down) earth frame; camera frame (forward, right, down) along the optical
axis. Angles in radians. Flat ground at the home altitude: height above ground = the vehicle's
relative altitude (GLOBAL_POSITION_INT.relative_alt).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20.common import GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME

EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class VehiclePose:
    """Vehicle position (deg, m AMSL, m above home) and attitude (rad, NED: roll, pitch, yaw)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    height_m: float
    roll: float
    pitch: float
    yaw: float


@dataclass(frozen=True)
class GimbalAttitude:
    """Gimbal pitch (rad, earth-referenced, negative = down) and yaw (rad) in vehicle or earth frame."""

    pitch: float
    yaw: float
    yaw_in_earth_frame: bool
    roll: float = 0.0  # rad; as reported (kept for a body-frame report, see gimbal_in_earth_frame)


@dataclass(frozen=True)
class GroundTarget:
    """Target position on the ground: degrees, m AMSL; horizontal range (m) and bearing (rad from north)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    ground_range_m: float
    bearing_rad: float


def quaternion_to_euler(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """MAVLink quaternion (w, x, y, z) -> (roll, pitch, yaw) rad, ZYX convention."""
    w, x, y, z = q
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"quaternion must be finite and non-zero, got {q}")
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def heading_rate(roll: float, pitch: float, pitch_rate: float, yaw_rate: float) -> float | None:
    """The rate of the Z-Y-X Euler yaw (the heading; rad/s, + = clockwise from above) from the body rates about the
    body's y and z axes (rad/s, ATTITUDE's pitchspeed and yawspeed) at roll and pitch (rad); None when pitched
    within 1 degree of vertical, where the heading is not defined. A tilted vehicle's heading turns with its pitch
    rate too: yawspeed alone is the turn about the tilted body axis."""
    cos_pitch = math.cos(pitch)
    if abs(cos_pitch) < math.sin(math.radians(1.0)):
        return None
    return (pitch_rate * math.sin(roll) + yaw_rate * math.cos(roll)) / cos_pitch


def gimbal_attitude_from_status(q: tuple[float, float, float, float], flags: int) -> GimbalAttitude:
    """GIMBAL_DEVICE_ATTITUDE_STATUS (q, flags) -> attitude; yaw is vehicle-relative unless flagged earth."""
    roll, pitch, yaw = quaternion_to_euler(q)
    return GimbalAttitude(pitch, yaw, bool(flags & GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME), roll)


def euler_rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """3x3 rotation of Z-Y-X Euler angles (rad): the rotated frame's (forward, right, down) axes as columns."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def gimbal_in_earth_frame(gimbal: GimbalAttitude, roll: float, pitch: float, yaw: float) -> GimbalAttitude:
    """A mount attitude reported against the vehicle's body (gimbal.attitude_frame: body; ArduPilot's servo
    mount reports its servo angles so, whatever its flags say) -> the optical axis as geo reads a report:
    earth-referenced pitch, yaw relative to the nose (rad). roll, pitch, yaw: the vehicle's (ATTITUDE, rad)."""
    axis = (euler_rotation(roll, pitch, yaw) @ euler_rotation(gimbal.roll, gimbal.pitch, gimbal.yaw))[:, 0]
    earth_pitch = math.asin(max(-1.0, min(1.0, -float(axis[2]))))
    relative_yaw = math.atan2(float(axis[1]), float(axis[0])) - yaw
    return GimbalAttitude(earth_pitch, math.atan2(math.sin(relative_yaw), math.cos(relative_yaw)), False)


def relative_gimbal_yaw(gimbal: GimbalAttitude, vehicle_yaw: float | None) -> float | None:
    """Gimbal yaw relative to the vehicle's nose (rad, + right); None if earth-framed and the heading is unknown."""
    if not gimbal.yaw_in_earth_frame:
        return gimbal.yaw
    if vehicle_yaw is None:
        return None
    return math.atan2(math.sin(gimbal.yaw - vehicle_yaw), math.cos(gimbal.yaw - vehicle_yaw))


def camera_ray_ned(yaw_error: float, pitch_error: float, gimbal: GimbalAttitude, vehicle_yaw: float) -> np.ndarray:
    """Unit NED direction of the ray through the target; errors as in control.gimbal.angular_error.

    The gimbal is assumed stabilised in roll and pitch (earth-referenced), as gimbal managers report.
    """
    # ray in the camera frame (forward, right, down): right = tan(yaw_err), up = tan(pitch_err)
    ray = np.array([1.0, math.tan(yaw_error), -math.tan(pitch_error)])
    yaw = gimbal.yaw if gimbal.yaw_in_earth_frame else vehicle_yaw + gimbal.yaw
    cp, sp, cy, sy = math.cos(gimbal.pitch), math.sin(gimbal.pitch), math.cos(yaw), math.sin(yaw)
    pitch_rot = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # about the right axis
    yaw_rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])  # about down
    ned = yaw_rot @ pitch_rot @ ray
    return ned / np.linalg.norm(ned)


def locate_on_ground(vehicle: VehiclePose, ray_ned: np.ndarray) -> GroundTarget | None:
    """Intersect the ray with flat ground `height_m` below the vehicle; None if it points above the horizon, or
    meets the flat ground beyond the real horizon (sqrt(2 R h): a grazing ray from a made-up height put the
    target thousands of km away, at a latitude past the pole that MAVLink's int32 degE7 could not carry, and
    the geo status raised; bench/fuzz.py), or at a latitude beyond +-90 deg. Longitude wrapped to [-180, 180)."""
    if vehicle.height_m <= 0 or ray_ned[2] <= 1e-6:
        return None
    scale = vehicle.height_m / ray_ned[2]
    north, east = float(ray_ned[0] * scale), float(ray_ned[1] * scale)
    ground_range = math.hypot(north, east)
    if not ground_range <= math.sqrt(2.0 * EARTH_RADIUS_M * vehicle.height_m):
        return None
    lat = vehicle.lat_deg + math.degrees(north / EARTH_RADIUS_M)
    cos_lat = math.cos(math.radians(vehicle.lat_deg))
    if not -90.0 <= lat <= 90.0 or cos_lat <= 1e-9:
        return None
    lon = (vehicle.lon_deg + math.degrees(east / (EARTH_RADIUS_M * cos_lat)) + 180.0) % 360.0 - 180.0
    return GroundTarget(lat, lon, vehicle.alt_amsl_m - vehicle.height_m, ground_range, math.atan2(east, north))


def ground_px_per_m(vehicle: VehiclePose, ray_ned: np.ndarray, yaw_error: float, pitch_error: float,
                    focal_px: float) -> float | None:
    """Image pixels per metre of side of a flat ground patch seen along `ray_ned` (unit NED), its side
    taken as sqrt(projected area); None if the ray misses the ground.

    A patch of area A m^2 at slant range R, the ray meeting the ground at grazing angle delta, covers
    the solid angle A sin(delta) / R^2; off the optical axis by theta (the angular errors, as in
    camera_ray_ned) a pixel covers cos(theta)^3 / focal_px^2 of solid angle. So the side in pixels
    is sqrt(A) * focal_px * sqrt(sin(delta)) / R / cos(theta)^1.5, with sin(delta) = the ray's down
    component and R = height / sin(delta) (flat ground, as locate_on_ground).
    """
    sin_grazing = float(ray_ned[2])
    if vehicle.height_m <= 0 or sin_grazing <= 1e-6 or focal_px <= 0:
        return None
    slant_m = vehicle.height_m / sin_grazing
    cos_off_axis = 1.0 / math.sqrt(1.0 + math.tan(yaw_error) ** 2 + math.tan(pitch_error) ** 2)
    return focal_px * math.sqrt(sin_grazing) / slant_m / cos_off_axis**1.5
