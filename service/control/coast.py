"""Coasting while the track is lost: keep the camera on the target's predicted ground position.

When the tracker reports "lost", the target usually keeps moving (a car under a canopy). Holding the
gimbal still lets it drive out of the view while the tracker's re-detection searches around the last
confident box, i.e. at a fixed IMAGE position. Coasting points the camera where the target is
predicted to be, offset from the camera axis as at the last confident frame, so the target stays near the
image position where it was lost; after `coast_s` the gimbal holds (zero rate), as without coasting.

Why a ground position, not an angular rate: with guidance the bearing barely moves while tracking and starts
to move only once the vehicle brakes (docs/service.md, "Control"). Each confident frame places the target on
flat ground (control.geo.locate_on_ground); its ground velocity is the least-squares slope of those positions
over the last `coast_fit_s`. While coasting the prediction is
    target(t) = target(t0) + velocity * integral of decay over [t0, t]
with decay 1 for the first half of coast_s after the last confident frame t0 (constant velocity: a car
does not stop under a canopy), then falling linearly to 0 at t0 + coast_s (the prediction comes to rest
instead of stopping the camera abruptly), and the camera is steered, per axis, by
    rate = d(planned angle)/dt + kp * (planned angle - measured camera angle)
where planned angle = direction from the vehicle's CURRENT position to the predicted target minus the
offset the target had from the camera axis at the last confident frame. The derivative is taken between consecutive coast frames (it
carries the vehicle's own motion); kp is the gimbal controller's; rates are clamped to max_rate and
slew-limited by max_accel like the tracking controller's.

Conventions: times in seconds of the frames' capture clock; positions in metres north / east of the
history's origin (the first sample's vehicle position; flat-earth offsets, fine over the few hundred
metres a track spans); angles in radians, earth frame: azimuth clockwise from north (camera azimuth =
vehicle yaw + vehicle-relative gimbal yaw, or the gimbal's earth-frame yaw), elevation = the gimbal's
earth-referenced pitch (+ up). Commanded yaw rates are vehicle-relative (MAVLink gimbal manager), so
the vehicle's own yaw rate is left to the feedback term.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from service.config import GimbalConfig
from service.control.geo import EARTH_RADIUS_M, GimbalAttitude, relative_gimbal_yaw

MIN_SAMPLES = 5  # confident frames needed for a velocity estimate


@dataclass(frozen=True)
class CoastParams:
    """coast_s: coasting time (s, 0 = hold at once); fit_window_s: history the velocity is fitted on
    (s); min_samples / min_span_s: least data for an estimate; kp: pointing feedback (1/s);
    max_rate (rad/s), max_accel (rad/s^2): the gimbal controller's limits; resume_change_m_s: a loss within
    fit_window_s of a re-acquisition resumes the coast it ended when the new fit differs by more (m/s)."""

    coast_s: float
    fit_window_s: float
    min_samples: int
    min_span_s: float
    kp: float
    max_rate: float
    max_accel: float
    resume_change_m_s: float = math.inf

    def __post_init__(self) -> None:
        if not (self.coast_s >= 0 and self.fit_window_s > 0 and self.min_samples >= 2 and self.min_span_s > 0
                and self.kp >= 0 and self.max_rate > 0 and self.max_accel > 0 and self.resume_change_m_s > 0):
            raise ValueError(f"invalid coast parameters {self}")

    @staticmethod
    def from_config(config: GimbalConfig) -> "CoastParams":
        """Degrees in the config -> radians; kp is the gimbal controller's; the history must span a third
        of the fit window (a velocity from 0.1 s of frames is mostly box jitter)."""
        return CoastParams(config.coast_s, config.coast_fit_s, MIN_SAMPLES, config.coast_fit_s / 3.0,
                           config.kp, math.radians(config.max_rate_deg_s), math.radians(config.max_accel_deg_s2),
                           config.coast_resume_change_m_s)


@dataclass(frozen=True)
class Position:
    """A geodetic position: degrees, and height above the (flat) ground in metres."""

    lat_deg: float
    lon_deg: float
    height_m: float = 0.0


@dataclass(frozen=True)
class Sighting:
    """One confident frame: capture time (s); vehicle and target (north, east) m from the history's
    origin; vehicle height above ground (m); camera (azimuth, elevation) rad."""

    time_s: float
    vehicle_ne: tuple[float, float]
    target_ne: tuple[float, float]
    height_m: float
    camera: tuple[float, float]


@dataclass(frozen=True)
class TrackHistory:
    """Recent confident frames, oldest first, at most fit_window_s before the newest; positions are
    relative to `origin` (lat, lon degrees), None while empty."""

    origin: tuple[float, float] | None = None
    samples: tuple[Sighting, ...] = ()


@dataclass(frozen=True)
class CoastPlan:
    """From the last confident frame: its time (s), the target's fitted (north, east) m then and its
    ground velocity (m/s), the target's (azimuth, elevation) offset from the camera axis then (rad,
    kept while coasting), the history's origin (degrees), the camera angles then (rad)."""

    start_s: float
    origin: tuple[float, float]
    target_ne: tuple[float, float]
    velocity_ne: tuple[float, float]
    offset: tuple[float, float]
    camera: tuple[float, float]


@dataclass(frozen=True)
class CoastState:
    """A coast in progress: the plan, the last commanded rates (yaw, pitch rad/s), the planned camera
    angles (azimuth, elevation rad) at the last step and that step's time (s)."""

    plan: CoastPlan
    last_rates: tuple[float, float]
    last_planned: tuple[float, float]
    last_time_s: float


def camera_angles(gimbal: GimbalAttitude, vehicle_yaw: float | None) -> tuple[float, float] | None:
    """Camera (azimuth, elevation) rad in the earth frame; None when a vehicle-relative yaw has no heading."""
    if gimbal.yaw_in_earth_frame:
        return gimbal.yaw, gimbal.pitch
    relative = relative_gimbal_yaw(gimbal, vehicle_yaw)
    if relative is None or vehicle_yaw is None:
        return None
    return wrap_pi(vehicle_yaw + relative), gimbal.pitch


def wrap_pi(angle: float) -> float:
    """Angle (rad) wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def north_east_m(origin: tuple[float, float], lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """(north, east) metres of a position from origin (lat, lon degrees); flat-earth approximation."""
    north = math.radians(lat_deg - origin[0]) * EARTH_RADIUS_M
    east = math.radians(lon_deg - origin[1]) * EARTH_RADIUS_M * math.cos(math.radians(origin[0]))
    return north, east


def remember(history: TrackHistory, time_s: float, vehicle: Position, target: Position,
             camera: tuple[float, float], window_s: float) -> TrackHistory:
    """Add a confident frame (vehicle and target positions, camera (azimuth, elevation) rad).

    A capture time not after the newest sample's (a restarted clock) starts a new history; samples
    older than window_s before time_s are dropped.
    """
    values = (time_s, vehicle.lat_deg, vehicle.lon_deg, vehicle.height_m, target.lat_deg, target.lon_deg, *camera)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"sighting must be finite: time {time_s}, vehicle {vehicle}, target {target}, camera {camera}")
    samples, origin = history.samples, history.origin
    if not samples or time_s <= samples[-1].time_s or origin is None:
        samples, origin = (), (vehicle.lat_deg, vehicle.lon_deg)
    new = Sighting(time_s, north_east_m(origin, vehicle.lat_deg, vehicle.lon_deg),
                   north_east_m(origin, target.lat_deg, target.lon_deg), vehicle.height_m, camera)
    kept = tuple(s for s in samples if s.time_s >= time_s - window_s)
    return TrackHistory(origin, kept + (new,))


def fit_line(times: list[float], values: list[float], at: float) -> tuple[float, float]:
    """Least-squares line through (times, values) -> (value at `at`, slope); times must not all be equal."""
    mean_t = math.fsum(times) / len(times)
    mean_v = math.fsum(values) / len(values)
    spread = math.fsum((t - mean_t) ** 2 for t in times)
    if spread <= 0:
        raise ValueError("a line fit needs at least two distinct times")
    slope = math.fsum((t - mean_t) * (v - mean_v) for t, v in zip(times, values)) / spread
    return mean_v + slope * (at - mean_t), slope


def plan_coast(history: TrackHistory, params: CoastParams) -> CoastPlan | None:
    """The target's fitted position and ground velocity at the last confident frame; None when
    coasting is off (coast_s 0) or the history is too short (< min_samples or spanning < min_span_s)."""
    samples = history.samples
    if params.coast_s <= 0 or history.origin is None or len(samples) < params.min_samples:
        return None
    if samples[-1].time_s - samples[0].time_s < params.min_span_s:
        return None
    times = [s.time_s for s in samples]
    last = samples[-1]
    north, v_north = fit_line(times, [s.target_ne[0] for s in samples], last.time_s)
    east, v_east = fit_line(times, [s.target_ne[1] for s in samples], last.time_s)
    azimuth, elevation = direction((north, east), last.vehicle_ne, last.height_m)
    offset = (wrap_pi(azimuth - last.camera[0]), elevation - last.camera[1])
    return CoastPlan(last.time_s, history.origin, (north, east), (v_north, v_east), offset, last.camera)


def velocity_change(plan: CoastPlan, other: CoastPlan) -> float:
    """Length (m/s) of the difference between two plans' ground velocities (north, east)."""
    return math.hypot(plan.velocity_ne[0] - other.velocity_ne[0], plan.velocity_ne[1] - other.velocity_ne[1])


def decay(elapsed_s: float, coast_s: float) -> float:
    """Weight of the fitted velocity: 1 up to coast_s / 2 after the last confident frame, then falling
    linearly to 0 at coast_s."""
    if coast_s <= 0 or elapsed_s >= coast_s:
        return 0.0
    half = coast_s / 2.0
    return 1.0 if elapsed_s <= half else 1.0 - (elapsed_s - half) / half


def decayed_travel_s(elapsed_s: float, coast_s: float) -> float:
    """Integral of decay over [0, elapsed_s] (s): how far the velocity has carried the prediction
    (at most 0.75 coast_s)."""
    if coast_s <= 0 or elapsed_s <= 0:
        return 0.0
    half = coast_s / 2.0
    if elapsed_s <= half:
        return elapsed_s
    over = min(elapsed_s, coast_s) - half
    return half + over - over * over / (2.0 * half)


def predicted_target_ne(plan: CoastPlan, elapsed_s: float, coast_s: float) -> tuple[float, float]:
    """Target (north, east) m at elapsed_s after the plan's start."""
    travel = decayed_travel_s(elapsed_s, coast_s)
    return plan.target_ne[0] + plan.velocity_ne[0] * travel, plan.target_ne[1] + plan.velocity_ne[1] * travel


def direction(target_ne: tuple[float, float], vehicle_ne: tuple[float, float], height_m: float) -> tuple[float, float]:
    """(azimuth, elevation) rad from the vehicle, height_m above flat ground, to a ground point."""
    d_north, d_east = target_ne[0] - vehicle_ne[0], target_ne[1] - vehicle_ne[1]
    return math.atan2(d_east, d_north), -math.atan2(height_m, math.hypot(d_north, d_east))


def planned_camera(plan: CoastPlan, target_ne: tuple[float, float], vehicle_ne: tuple[float, float],
                   height_m: float) -> tuple[float, float]:
    """Camera (azimuth, elevation) rad that keeps target_ne at the plan's offset from the camera axis."""
    azimuth, elevation = direction(target_ne, vehicle_ne, height_m)
    return wrap_pi(azimuth - plan.offset[0]), elevation - plan.offset[1]


def start_coast(plan: CoastPlan, last_rates: tuple[float, float]) -> CoastState:
    """The coast state at the plan's start: the camera angles then, and the tracking controller's last
    rates (yaw, pitch rad/s) as the slew reference."""
    return CoastState(plan, last_rates, plan.camera, plan.start_s)


def coast_step(state: CoastState, now_s: float, vehicle: Position | None, camera: tuple[float, float] | None,
               params: CoastParams) -> tuple[CoastState, tuple[float, float] | None]:
    """One lost frame at capture time now_s, with the vehicle's position and the measured camera
    (azimuth, elevation) rad -> (new state, (yaw_rate, pitch_rate) rad/s); rates None = the coast is
    over, hold: after coast_s, a capture time not after the last step's, or no vehicle / camera data."""
    plan = state.plan
    elapsed = now_s - plan.start_s
    if vehicle is None or camera is None or not math.isfinite(now_s) or now_s <= state.last_time_s \
            or elapsed >= params.coast_s or vehicle.height_m <= 0:
        return state, None
    vehicle_ne = north_east_m(plan.origin, vehicle.lat_deg, vehicle.lon_deg)
    target_ne = predicted_target_ne(plan, elapsed, params.coast_s)
    planned = planned_camera(plan, target_ne, vehicle_ne, vehicle.height_m)
    dt = now_s - state.last_time_s
    feed_forward = (wrap_pi(planned[0] - state.last_planned[0]) / dt, (planned[1] - state.last_planned[1]) / dt)
    raw = (feed_forward[0] + params.kp * wrap_pi(planned[0] - camera[0]),
           feed_forward[1] + params.kp * (planned[1] - camera[1]))
    rates = (_limited(raw[0], state.last_rates[0], dt, params), _limited(raw[1], state.last_rates[1], dt, params))
    return CoastState(plan, rates, planned, now_s), rates


def _limited(raw: float, last: float, dt: float, params: CoastParams) -> float:
    """Clamp to max_rate, then slew-limit from `last` over dt."""
    rate = max(-params.max_rate, min(params.max_rate, raw))
    step = params.max_accel * dt
    return last + max(-step, min(step, rate - last))
