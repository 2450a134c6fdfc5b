"""Pure model of a multicopter with a 2-axis gimbal, as ArduCopter or PX4 treats the service's messages.

Functional core of the mock autopilot: no sockets, no wall clock. The caller supplies the time
(`now_s`, seconds on the caller's clock: simulated time in the closed loop, wall time in real-time
runs) and steps the dynamics with `step(dt_s)`.

Frames and units: local NED position in metres from home (north, east, down); velocities m/s in NED;
vehicle yaw radians clockwise from north; gimbal pitch radians in the earth frame (stabilised,
0 = horizon, negative = down), gimbal yaw radians relative to the vehicle heading (positive = right).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

Flavour = Literal["ardupilot", "px4"]
FLAVOURS: tuple[str, ...] = ("ardupilot", "px4")

# ArduCopter custom_mode numbers (the subset the service may meet).
ARDUCOPTER_MODES = {"STABILIZE": 0, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6,
                    "LAND": 9, "POSHOLD": 16, "FOLLOW": 23}
# PX4: custom_mode = main_mode << 16 | sub_mode << 24 (px4_custom_mode.h).
PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6, "STABILIZED": 7}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6,
                "FOLLOW_TARGET": 8}
PX4_MODES = {"POSCTL": (3, 0), "OFFBOARD": (6, 0), "HOLD": (4, 3), "FOLLOW_TARGET": (4, 8),
             "MANUAL": (1, 0), "ALTCTL": (2, 0)}

# type_mask bits of SET_POSITION_TARGET_LOCAL_NED: a set bit means "ignore this field".
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 8, 16, 32
IGNORE_YAW_RATE = 2048
FRAME_LOCAL_NED, FRAME_BODY_NED, FRAME_BODY_OFFSET_NED = 1, 8, 9
GRAVITY_M_S2 = 9.80665


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4 heartbeat custom_mode: main mode in bits 16..23, sub mode in bits 24..31."""
    return (main_mode << 16) | (sub_mode << 24)


def custom_mode_of(flavour: Flavour, mode: str) -> int:
    """Heartbeat custom_mode of a named flight mode for the firmware `flavour` (ValueError if unknown)."""
    if flavour == "ardupilot":
        if mode not in ARDUCOPTER_MODES:
            raise ValueError(f"unknown ArduCopter mode {mode!r}; known: {sorted(ARDUCOPTER_MODES)}")
        return ARDUCOPTER_MODES[mode]
    if flavour == "px4":
        if mode not in PX4_MODES:
            raise ValueError(f"unknown PX4 mode {mode!r}; known: {sorted(PX4_MODES)}")
        return px4_custom_mode(*PX4_MODES[mode])
    raise ValueError(f"unknown autopilot flavour {flavour!r}; expected one of {FLAVOURS}")


def guidance_mode(flavour: Flavour) -> str:
    """The mode in which the firmware honours external velocity setpoints (GUIDED / OFFBOARD)."""
    return "GUIDED" if flavour == "ardupilot" else "OFFBOARD"


def follow_mode(flavour: Flavour) -> str:
    """The mode in which the firmware follows FOLLOW_TARGET (FOLLOW / Follow-Me)."""
    return "FOLLOW" if flavour == "ardupilot" else "FOLLOW_TARGET"


def wrap_pi(angle: float) -> float:
    """Angle in radians wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def clamp(value: float, low: float, high: float) -> float:
    """`value` limited to [low, high]."""
    return min(max(value, low), high)


def lean(accel_ne: tuple[float, float], velocity_ne: tuple[float, float], yaw: float,
         drag_per_s: float) -> tuple[float, float]:
    """(roll, pitch) rad of a multicopter whose thrust gives horizontal acceleration accel_ne (m/s/s) against
    linear drag (drag_per_s * velocity, m/s): it tilts its thrust that way; pitch negative = nose down."""
    a_n = accel_ne[0] + drag_per_s * velocity_ne[0]
    a_e = accel_ne[1] + drag_per_s * velocity_ne[1]
    forward = math.cos(yaw) * a_n + math.sin(yaw) * a_e
    right = -math.sin(yaw) * a_n + math.cos(yaw) * a_e
    return math.atan2(right, GRAVITY_M_S2), -math.atan2(forward, GRAVITY_M_S2)


def rotation_zyx(roll: float, pitch: float, yaw: float) -> list[list[float]]:
    """3x3 rotation (rows) of Z-Y-X Euler angles in rad: the rotated frame's (forward, right, down) axes as columns."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    return [[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp]]


def mount_angles_in_body(vehicle_rpy: tuple[float, float, float], camera_pitch: float,
                         camera_yaw: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of a mount against the vehicle's body, for a camera held level at earth pitch
    camera_pitch and yaw camera_yaw relative to the nose (rad): what ArduPilot's servo mount reports."""
    roll, pitch, yaw = vehicle_rpy
    v = rotation_zyx(roll, pitch, yaw)
    c = rotation_zyx(0.0, camera_pitch, yaw + camera_yaw)
    m = [[sum(v[k][i] * c[k][j] for k in range(3)) for j in range(3)] for i in range(3)]  # v^T c
    return (math.atan2(m[2][1], m[2][2]), math.asin(max(-1.0, min(1.0, -m[2][0]))), math.atan2(m[1][0], m[0][0]))


def approach(current: float, target: float, max_step: float) -> float:
    """Move `current` towards `target` by at most `max_step` (rate / acceleration limiting)."""
    return current + clamp(target - current, -max_step, max_step)


@dataclass(frozen=True)
class VehicleConfig:
    """Dynamics limits and firmware timing. Angles in degrees here for readability; the model uses radians."""

    flavour: Flavour = "ardupilot"
    system_id: int = 1
    home_lat_deg: float = 47.397742  # any fixed place: the flat-earth model only needs a reference
    home_lon_deg: float = 8.545594
    home_alt_m: float = 488.0  # AMSL of the ground plane
    start_altitude_m: float = 40.0  # above ground
    start_mode: str = ""  # "" = the firmware's guidance mode (GUIDED / OFFBOARD)
    max_speed_m_s: float = 12.0
    # ArduCopter GUIDED reached 1.7 m/s 1 s and 4.1 m/s 2 s after a 5 m/s velocity target (SITL, WPNAV_ACCEL
    # 250 cm/s/s with jerk limiting); PX4's MPC_ACC_HOR is 3 m/s/s. Was 4.0 before the firmware was at hand.
    max_accel_m_s2: float = 2.5
    # The vehicle leans into its acceleration plus a drag term: ArduCopter SITL flew 4.8 m/s pitched 12 degrees
    # nose down (tan 12.2 deg * g / 4.8 m/s = 0.44 /s) and leaned 19 degrees while speeding up.
    drag_per_s: float = 0.44
    max_yaw_rate_deg_s: float = 90.0
    gimbal_max_rate_deg_s: float = 120.0
    gimbal_pitch_min_deg: float = -90.0  # ArduPilot: MNT1_PITCH_MIN / MAX of the servo gimbal the SITL tests use
    gimbal_pitch_max_deg: float = 20.0
    # PX4 (MNT_MODE_OUT 0) keeps the pitch within +-MNT_RANGE_PITCH / 2: SIH with the default 90 stopped a
    # 60 deg/s pitch-down command at -45 deg (yaw went on past 120 deg)
    px4_pitch_range_deg: float = 90.0
    gimbal_yaw_min_deg: float = -160.0
    gimbal_yaw_max_deg: float = 160.0
    gimbal_start_pitch_deg: float = -45.0
    # ArduCopter GUIDED: a velocity target older than 3 s is replaced by zero velocity (vehicle stops).
    ardupilot_guided_timeout_s: float = 3.0
    # PX4 OFFBOARD: COM_OF_LOSS_T. PX4 SIH (main, 2025) left OFFBOARD 1.0 s after the last setpoint (was 0.5 s,
    # the default of older releases, before the firmware was at hand).
    px4_offboard_loss_s: float = 1.0
    # PX4 refuses to enter OFFBOARD unless setpoints have streamed (> 2 Hz) for about 1 s.
    px4_offboard_prestream_s: float = 1.0
    follow_distance_m: float = 15.0
    follow_timeout_s: float = 3.0

    def __post_init__(self) -> None:
        if self.flavour not in FLAVOURS:
            raise ValueError(f"flavour must be one of {FLAVOURS}, got {self.flavour!r}")
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"system_id must be 1..255, got {self.system_id}")
        if self.start_mode:
            custom_mode_of(self.flavour, self.start_mode)
        if not self.drag_per_s >= 0:
            raise ValueError(f"drag_per_s must be >= 0, got {self.drag_per_s}")
        for name in ("max_speed_m_s", "max_accel_m_s2", "max_yaw_rate_deg_s", "gimbal_max_rate_deg_s",
                     "ardupilot_guided_timeout_s", "px4_offboard_loss_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")

    @property
    def pitch_limits_deg(self) -> tuple[float, float]:
        """(lowest, highest) gimbal pitch in degrees the firmware allows."""
        if self.flavour == "px4":
            half = self.px4_pitch_range_deg / 2.0
            return max(self.gimbal_pitch_min_deg, -half), min(self.gimbal_pitch_max_deg, half)
        return self.gimbal_pitch_min_deg, self.gimbal_pitch_max_deg

    @property
    def setpoint_timeout_s(self) -> float:
        """How long the firmware keeps acting on the last velocity setpoint."""
        return self.ardupilot_guided_timeout_s if self.flavour == "ardupilot" else self.px4_offboard_loss_s


@dataclass
class VehicleState:
    """Kinematic state: NED metres / m/s, yaw rad (clockwise from north), gimbal rad (see module doc)."""

    north: float = 0.0
    east: float = 0.0
    down: float = -40.0
    v_north: float = 0.0
    v_east: float = 0.0
    v_down: float = 0.0
    yaw: float = 0.0
    yaw_rate: float = 0.0
    roll: float = 0.0  # rad, right side down positive: the lean into sideways acceleration and drag
    pitch: float = 0.0  # rad, nose up positive: negative while speeding up forwards
    gimbal_pitch: float = math.radians(-45.0)
    gimbal_yaw: float = 0.0
    gimbal_pitch_rate: float = 0.0
    gimbal_yaw_rate: float = 0.0


@dataclass(frozen=True)
class VehicleSnapshot:
    """What the closed loop renders and records, from the mock or from firmware: NED metres / m/s in the scene's
    frame, vehicle yaw rad clockwise from north, gimbal pitch rad (earth frame) and yaw rad (vehicle frame), the
    flight mode's name."""

    north: float
    east: float
    down: float
    yaw: float
    gimbal_pitch: float
    gimbal_yaw: float
    v_north: float
    v_east: float
    mode: str


@dataclass(frozen=True)
class ReceivedCommand:
    """One MAVLink message the autopilot received: when (caller's clock), from whom, what it did with it."""

    time_s: float
    link: str
    src_system: int
    src_component: int
    msg_type: str
    fields: dict
    outcome: str  # "applied", "ignored: <why>", "ack <result>", "forwarded", "dropped: link down"


@dataclass
class VelocityTarget:
    """Commanded velocity in NED m/s and yaw rate rad/s, with the time it was received."""

    v_north: float
    v_east: float
    v_down: float
    yaw_rate: float
    received_s: float


@dataclass
class FollowTarget:
    """Last FOLLOW_TARGET position in local NED metres, with its time."""

    north: float
    east: float
    received_s: float


@dataclass
class VehicleModel:
    """Mock ArduCopter / PX4 vehicle + gimbal: message handling and dynamics, stepped by the caller."""

    config: VehicleConfig = field(default_factory=VehicleConfig)
    state: VehicleState = field(default_factory=VehicleState)
    mode: str = ""
    armed: bool = True
    time_s: float = 0.0
    velocity_target: VelocityTarget | None = None
    follow_target: FollowTarget | None = None
    gimbal_primary: tuple[int, int] = (0, 0)  # (sysid, compid) in control of the gimbal (PX4 manager)
    gimbal_rate_target: tuple[float, float] = (0.0, 0.0)  # (pitch, yaw) rad/s
    gimbal_angle_target: tuple[float, float] | None = None  # (pitch, yaw) rad, when in angle mode
    setpoint_times: list[float] = field(default_factory=list)  # recent setpoint arrivals (PX4 pre-stream)
    events: list[tuple[float, str]] = field(default_factory=list)  # mode changes, failsafes

    def __post_init__(self) -> None:
        if not self.mode:
            self.mode = self.config.start_mode or guidance_mode(self.config.flavour)
        self.state.down = -self.config.start_altitude_m
        self.state.gimbal_pitch = math.radians(self.config.gimbal_start_pitch_deg)

    def snapshot(self) -> VehicleSnapshot:
        """The state the closed loop renders and records (see VehicleSnapshot)."""
        st = self.state
        return VehicleSnapshot(st.north, st.east, st.down, st.yaw, st.gimbal_pitch, st.gimbal_yaw, st.v_north,
                               st.v_east, self.mode)

    # ----- identity -----------------------------------------------------------------------------
    @property
    def custom_mode(self) -> int:
        """Heartbeat custom_mode of the current flight mode."""
        return custom_mode_of(self.config.flavour, self.mode)

    @property
    def in_guidance_mode(self) -> bool:
        """True in GUIDED (ArduCopter) / OFFBOARD (PX4): external velocity setpoints are honoured."""
        return self.mode == guidance_mode(self.config.flavour)

    def operator_set_mode(self, mode: str) -> None:
        """The pilot switches mode (RC / ground station); PX4 refuses OFFBOARD without a setpoint stream."""
        custom_mode_of(self.config.flavour, mode)
        if self.config.flavour == "px4" and mode == "OFFBOARD":
            window = self.config.px4_offboard_prestream_s
            recent = [t for t in self.setpoint_times if self.time_s - t <= window]
            # > 2 Hz over the last second, and the newest one still fresh.
            if len(recent) < 2 * window + 1 or self.time_s - recent[-1] > self.config.px4_offboard_loss_s:
                raise ValueError("PX4 rejects OFFBOARD: no setpoint stream (> 2 Hz for 1 s) before the switch")
        self._set_mode(mode, "operator")

    def _set_mode(self, mode: str, why: str) -> None:
        if mode != self.mode:
            self.events.append((self.time_s, f"mode {self.mode} -> {mode} ({why})"))
            self.mode = mode
            self.velocity_target = None

    # ----- messages -----------------------------------------------------------------------------
    def set_gimbal_rates(self, pitch_rate: float, yaw_rate: float) -> None:
        """Rate mode: angular rates in rad/s (positive = up / right), NaN taken as 0."""
        self.gimbal_rate_target = (0.0 if math.isnan(pitch_rate) else pitch_rate,
                                   0.0 if math.isnan(yaw_rate) else yaw_rate)
        self.gimbal_angle_target = None

    def set_gimbal_angles(self, pitch: float, yaw: float) -> None:
        """Angle mode: pitch (earth frame) and yaw (vehicle frame) in radians."""
        self.gimbal_angle_target = (pitch, yaw)
        self.gimbal_rate_target = (0.0, 0.0)

    def set_velocity(self, frame: int, type_mask: int, vx: float, vy: float, vz: float, yaw_rate: float,
                     now_s: float) -> str:
        """Apply a SET_POSITION_TARGET_LOCAL_NED velocity setpoint; returns the outcome for the record."""
        if self.config.flavour == "px4" and frame == FRAME_BODY_OFFSET_NED:
            # PX4 refuses it ("SET_POSITION_TARGET_LOCAL_NED coordinate frame 9 unsupported"): not a setpoint,
            # and not part of the stream that lets the pilot engage OFFBOARD
            return "ignored: PX4 does not take coordinate frame 9 (MAV_FRAME_BODY_OFFSET_NED)"
        self.setpoint_times.append(now_s)
        del self.setpoint_times[:-64]
        if not self.in_guidance_mode:
            return f"ignored: mode {self.mode} is not {guidance_mode(self.config.flavour)}"
        if frame not in (FRAME_LOCAL_NED, FRAME_BODY_NED, FRAME_BODY_OFFSET_NED):
            return f"ignored: coordinate frame {frame} not supported"
        values = [0.0 if (type_mask & bit) else v for bit, v in
                  ((IGNORE_VX, vx), (IGNORE_VY, vy), (IGNORE_VZ, vz))]
        if not all(math.isfinite(v) for v in values):
            return "ignored: non-finite velocity"
        rate = 0.0 if (type_mask & IGNORE_YAW_RATE) or not math.isfinite(yaw_rate) else yaw_rate
        forward, right, down = values
        if frame == FRAME_LOCAL_NED:
            north, east = forward, right
        else:  # body frames: x forward, y right along the current heading
            c, s = math.cos(self.state.yaw), math.sin(self.state.yaw)
            north, east = c * forward - s * right, s * forward + c * right
        self.velocity_target = VelocityTarget(north, east, down, rate, now_s)
        return "applied"

    def set_follow_target(self, north: float, east: float, src_system: int, now_s: float) -> str:
        """Apply a FOLLOW_TARGET position (local NED metres) as each firmware does."""
        if self.config.flavour == "ardupilot" and src_system == self.config.system_id:
            # ArduCopter FOLLOW ignores FOLLOW_TARGET carrying its own system id (AP_Follow).
            return "ignored: ArduPilot FOLLOW ignores its own system id"
        self.follow_target = FollowTarget(north, east, now_s)
        if self.mode != follow_mode(self.config.flavour):
            return f"stored: mode {self.mode} is not {follow_mode(self.config.flavour)}"
        return "applied"

    def configure_gimbal_manager(self, primary_sysid: float, primary_compid: float,
                                 src: tuple[int, int]) -> str:
        """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE p1/p2: -1 unchanged, -2 the sender, -3 release."""
        if primary_sysid == -1:
            return "applied (unchanged)"
        if primary_sysid == -2:
            self.gimbal_primary = src
        elif primary_sysid == -3:  # release, only by the one in control (ArduCopter SITL ignores others')
            if tuple(src) != self.gimbal_primary:
                return "applied (unchanged: the sender is not in control)"
            self.gimbal_primary = (0, 0)
        else:
            self.gimbal_primary = (int(primary_sysid), int(primary_compid))
        self.events.append((self.time_s, f"gimbal primary control {self.gimbal_primary}"))
        return "applied"

    # ----- dynamics -----------------------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """Advance the vehicle and gimbal by `dt_s` seconds (timeouts, then rate/accel-limited motion)."""
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        cfg, st = self.config, self.state
        self.time_s += dt_s
        self._apply_timeouts()
        target_n = target_e = target_d = target_yaw_rate = 0.0
        if self.velocity_target is not None and self.in_guidance_mode:
            vt = self.velocity_target
            target_n, target_e, target_d, target_yaw_rate = vt.v_north, vt.v_east, vt.v_down, vt.yaw_rate
        elif self.mode == follow_mode(cfg.flavour) and self.follow_target is not None:
            target_n, target_e, target_yaw_rate = self._follow_velocity()
        speed = math.hypot(target_n, target_e)
        if speed > cfg.max_speed_m_s:
            target_n, target_e = target_n * cfg.max_speed_m_s / speed, target_e * cfg.max_speed_m_s / speed
        target_d = clamp(target_d, -3.0, 3.0)
        dv = cfg.max_accel_m_s2 * dt_s
        v_north, v_east = st.v_north, st.v_east
        st.v_north = approach(st.v_north, target_n, dv)
        st.v_east = approach(st.v_east, target_e, dv)
        st.roll, st.pitch = lean(((st.v_north - v_north) / dt_s, (st.v_east - v_east) / dt_s),
                                 (st.v_north, st.v_east), st.yaw, cfg.drag_per_s)
        st.v_down = approach(st.v_down, target_d, dv)
        max_yaw_rate = math.radians(cfg.max_yaw_rate_deg_s)
        st.yaw_rate = clamp(target_yaw_rate, -max_yaw_rate, max_yaw_rate)
        st.north += st.v_north * dt_s
        st.east += st.v_east * dt_s
        st.down = min(st.down + st.v_down * dt_s, -2.0)  # never below 2 m above ground
        st.yaw = wrap_pi(st.yaw + st.yaw_rate * dt_s)
        self._step_gimbal(dt_s)

    def _apply_timeouts(self) -> None:
        cfg = self.config
        vt = self.velocity_target
        if vt is not None and self.time_s - vt.received_s > cfg.setpoint_timeout_s:
            self.velocity_target = None
            if cfg.flavour == "px4" and self.mode == "OFFBOARD":
                # Offboard loss failsafe: PX4 SIH switched to Position mode (POSCTL, "Failsafe activated") and
                # held there (was Hold before the firmware was at hand); the pilot must re-engage.
                self._set_mode("POSCTL", "offboard setpoint stream lost")
            else:
                self.events.append((self.time_s, "guided setpoint timeout: stopping"))
        ft = self.follow_target
        if ft is not None and self.time_s - ft.received_s > cfg.follow_timeout_s:
            self.follow_target = None
            self.events.append((self.time_s, "follow target timeout: holding"))

    def _follow_velocity(self) -> tuple[float, float, float]:
        """Velocity (NED m/s) and yaw rate (rad/s) towards `follow_distance_m` from the follow target."""
        ft, st, cfg = self.follow_target, self.state, self.config
        assert ft is not None
        dn, de = ft.north - st.north, ft.east - st.east
        dist = math.hypot(dn, de)
        if dist < 1e-6:
            return 0.0, 0.0, 0.0
        gain = 0.5  # 1/s: closes half the distance error per second, like a P position controller
        excess = dist - cfg.follow_distance_m
        heading_error = wrap_pi(math.atan2(de, dn) - st.yaw)
        return gain * excess * dn / dist, gain * excess * de / dist, 1.0 * heading_error

    def _step_gimbal(self, dt_s: float) -> None:
        cfg, st = self.config, self.state
        max_rate = math.radians(cfg.gimbal_max_rate_deg_s)
        if self.gimbal_angle_target is not None:
            pitch_t, yaw_t = self.gimbal_angle_target
            pitch_rate = clamp((pitch_t - st.gimbal_pitch) / dt_s, -max_rate, max_rate)
            yaw_rate = clamp(wrap_pi(yaw_t - st.gimbal_yaw) / dt_s, -max_rate, max_rate)
        else:
            pitch_rate = clamp(self.gimbal_rate_target[0], -max_rate, max_rate)
            yaw_rate = clamp(self.gimbal_rate_target[1], -max_rate, max_rate)
        low, high = cfg.pitch_limits_deg
        pitch = clamp(st.gimbal_pitch + pitch_rate * dt_s, math.radians(low), math.radians(high))
        yaw = clamp(st.gimbal_yaw + yaw_rate * dt_s, math.radians(cfg.gimbal_yaw_min_deg),
                    math.radians(cfg.gimbal_yaw_max_deg))
        st.gimbal_pitch_rate = (pitch - st.gimbal_pitch) / dt_s
        st.gimbal_yaw_rate = (yaw - st.gimbal_yaw) / dt_s
        st.gimbal_pitch, st.gimbal_yaw = pitch, yaw

    # ----- geodesy (flat earth around home) -----------------------------------------------------
    def lat_lon_of(self, north: float, east: float) -> tuple[float, float]:
        """Local NED metres -> latitude, longitude in degrees (equirectangular around home)."""
        earth_radius = 6378137.0
        lat = self.config.home_lat_deg + math.degrees(north / earth_radius)
        lon = self.config.home_lon_deg + math.degrees(
            east / (earth_radius * math.cos(math.radians(self.config.home_lat_deg))))
        return lat, lon

    def local_of(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """Latitude, longitude in degrees -> local (north, east) metres from home."""
        earth_radius = 6378137.0
        north = math.radians(lat_deg - self.config.home_lat_deg) * earth_radius
        east = math.radians(lon_deg - self.config.home_lon_deg) * earth_radius * math.cos(
            math.radians(self.config.home_lat_deg))
        return north, east
