"""Gimbal rate control: image error -> angular error -> PI(D) -> rate-limited gimbal rates.

Conventions: angles in radians, rates in rad/s. Angular error (yaw_err, pitch_err) is the angle from
the optical axis to the target: yaw positive = target right of centre, pitch positive = target above
centre; a positive rate therefore turns the camera towards the target (MAVLink: pitch up, yaw right).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from service.config import GimbalConfig


def focal_length_px(image_width: int, hfov_rad: float) -> float:
    """Pinhole focal length in pixels from the image width (px) and horizontal field of view (rad)."""
    if image_width <= 0 or not 0 < hfov_rad < math.pi:
        raise ValueError(f"need width > 0 and 0 < hfov < pi, got {image_width}, {hfov_rad}")
    return (image_width / 2.0) / math.tan(hfov_rad / 2.0)


def angular_error(box: tuple[float, float, float, float], image_size: tuple[int, int],
                  hfov_rad: float) -> tuple[float, float]:
    """(yaw_err, pitch_err) rad of the box centre from the image centre; box (x, y, w, h) px, size (w, h).

    Square pixels: the vertical focal length equals the horizontal one.
    """
    width, height = image_size
    focal = focal_length_px(width, hfov_rad)
    x, y, w, h = box
    u, v = x + w / 2.0, y + h / 2.0
    return math.atan2(u - width / 2.0, focal), math.atan2(height / 2.0 - v, focal)


@dataclass(frozen=True)
class AxisState:
    """One axis' controller memory: integral of error (rad*s), last error (rad), last output (rad/s)."""

    integral: float = 0.0
    last_error: float | None = None
    last_output: float = 0.0


@dataclass(frozen=True)
class PidGains:
    """Gains and limits in SI units (rad, s)."""

    kp: float
    ki: float
    kd: float
    max_rate: float  # rad/s
    max_accel: float  # rad/s^2, slew limit on the output
    integrator_limit: float  # rad/s, bound on |ki * integral|
    deadband: float  # rad

    @staticmethod
    def from_config(config: GimbalConfig) -> "PidGains":
        """Convert the config's degree units to radians."""
        rad = math.radians
        return PidGains(config.kp, config.ki, config.kd, rad(config.max_rate_deg_s),
                        rad(config.max_accel_deg_s2), rad(config.integrator_limit_deg_s), rad(config.deadband_deg))


def pid_step(state: AxisState, error: float, dt: float, gains: PidGains) -> tuple[AxisState, float]:
    """One PI(D) step on `error` (rad) over dt (s) -> (new state, rate rad/s) within rate and slew limits.

    Anti-windup: the integral is clamped to integrator_limit and does not grow while the output is
    saturated in the direction of the error (conditional integration).
    """
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt}")
    if not math.isfinite(error):
        raise ValueError(f"error must be finite, got {error}")
    if abs(error) < gains.deadband:
        error = 0.0
    derivative = 0.0 if state.last_error is None else (error - state.last_error) / dt
    integral = state.integral + error * dt
    if gains.ki > 0:
        bound = gains.integrator_limit / gains.ki
        integral = max(-bound, min(bound, integral))
    else:
        integral = 0.0
    raw = gains.kp * error + gains.ki * integral + gains.kd * derivative
    limited = _clamp(raw, gains.max_rate)
    max_step = gains.max_accel * dt
    limited = state.last_output + _clamp(limited - state.last_output, max_step)
    saturated = abs(limited - raw) > 1e-12
    if saturated and error * raw > 0:
        integral = state.integral  # conditional integration: do not wind up against the limit
    return AxisState(integral=integral, last_error=error, last_output=limited), limited


@dataclass(frozen=True)
class GimbalState:
    """Both axes' memory; GimbalState() is the reset state (after lost / stop)."""

    yaw: AxisState = AxisState()
    pitch: AxisState = AxisState()


def gimbal_step(state: GimbalState, yaw_error: float, pitch_error: float, dt: float,
                gains: PidGains) -> tuple[GimbalState, float, float]:
    """Both axes -> (new state, yaw_rate, pitch_rate) rad/s."""
    yaw_state, yaw_rate = pid_step(state.yaw, yaw_error, dt, gains)
    pitch_state, pitch_rate = pid_step(state.pitch, pitch_error, dt, gains)
    return GimbalState(yaw_state, pitch_state), yaw_rate, pitch_rate


def vehicle_frame_yaw_rate(camera_yaw_rate: float, heading_rate: float | None, max_rate: float) -> float:
    """The gimbal's yaw rate relative to the vehicle (rad/s, what a YAW_IN_VEHICLE_FRAME command carries) that turns
    the camera at camera_yaw_rate (rad/s, about the vertical) while the vehicle's heading turns at heading_rate
    (rad/s, None = unknown: no correction), within +-max_rate.

    A gimbal whose yaw is held relative to the nose turns with the vehicle: without this the image-error loop
    meets every turn of the vehicle (velocity guidance turning after the target) as a disturbance, which its
    integrator, bounded, takes seconds to cancel.
    """
    if heading_rate is None:
        return camera_yaw_rate
    return _clamp(camera_yaw_rate - heading_rate, max_rate)


def _clamp(value: float, bound: float) -> float:
    return max(-bound, min(bound, value))
