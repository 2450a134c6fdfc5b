"""MAVLink message builders (pure: pymavlink `*_encode`, no I/O) for the camera, gimbal and guidance.

Normalised image coordinates 0..1 (top-left origin); rates rad/s, positive = pitch up / yaw right;
velocities m/s body frame (forward, right, down).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20.common import (
    CAMERA_CAP_FLAGS_HAS_TRACKING_GEO_STATUS, CAMERA_CAP_FLAGS_HAS_TRACKING_POINT, CAMERA_CAP_FLAGS_HAS_TRACKING_RECTANGLE,
    CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM,
    CAMERA_TRACKING_MODE_NONE, CAMERA_TRACKING_MODE_POINT, CAMERA_TRACKING_MODE_RECTANGLE,
    CAMERA_TRACKING_STATUS_FLAGS_ACTIVE, CAMERA_TRACKING_STATUS_FLAGS_COASTING, CAMERA_TRACKING_STATUS_FLAGS_ERROR,
    CAMERA_TRACKING_STATUS_FLAGS_IDLE, CAMERA_TRACKING_TARGET_DATA_IN_STATUS, GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME,
    MAV_AUTOPILOT_INVALID, MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, MAV_FRAME_BODY_NED, MAV_STATE_ACTIVE,
    MAV_STATE_CRITICAL, MAV_TYPE_CAMERA,
)

from service.control.geo import GroundTarget
from service.control.guidance import VELOCITY_YAW_RATE_TYPE_MASK, VelocitySetpoint
from service.domain import LoopState, SelectionKind, TrackSnapshot

NAN = float("nan")
NO_TARGET_DATA = 0  # CAMERA_TRACKING_TARGET_DATA is a bitmask: no bit set = no target data
FOLLOW_TARGET_CAP_POSITION = 1  # FOLLOW_TARGET.est_capabilities bit 0 (position); MAVLink names no enum for it


@dataclass(frozen=True)
class TrackingStatus:
    """What 275 reports: status flag, mode, and the target's normalised box (x, y, w, h) or None."""

    status: int = CAMERA_TRACKING_STATUS_FLAGS_IDLE
    mode: int = CAMERA_TRACKING_MODE_NONE
    box: tuple[float, float, float, float] | None = None


def tracking_status(snapshot: TrackSnapshot) -> TrackingStatus:
    """The loop's snapshot in 275's terms: idle -> IDLE, lost -> COASTING, tracking / recovered -> ACTIVE;
    mode from the selection (NONE while idle)."""
    if snapshot.state == LoopState.IDLE:
        return TrackingStatus(CAMERA_TRACKING_STATUS_FLAGS_IDLE, CAMERA_TRACKING_MODE_NONE, snapshot.box_normalised)
    lost = snapshot.state == LoopState.LOST
    status = CAMERA_TRACKING_STATUS_FLAGS_COASTING if lost else CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
    modes = {SelectionKind.POINT: CAMERA_TRACKING_MODE_POINT, SelectionKind.RECTANGLE: CAMERA_TRACKING_MODE_RECTANGLE}
    mode = modes.get(snapshot.selection, CAMERA_TRACKING_MODE_NONE)  # type: ignore[arg-type]
    return TrackingStatus(status, mode, snapshot.box_normalised)


def with_source_state(status: TrackingStatus, source_ok: bool) -> TrackingStatus:
    """A track whose camera has failed is reported as ERROR (keeping mode and last box); idle stays idle."""
    if source_ok or status.status == CAMERA_TRACKING_STATUS_FLAGS_IDLE:
        return status
    return TrackingStatus(CAMERA_TRACKING_STATUS_FLAGS_ERROR, status.mode, status.box)


def heartbeat(mav: object, healthy: bool) -> object:
    """Camera heartbeat: MAV_TYPE_CAMERA, autopilot INVALID; CRITICAL while the frame source is failing."""
    return mav.heartbeat_encode(MAV_TYPE_CAMERA, MAV_AUTOPILOT_INVALID, 0, 0,  # type: ignore[attr-defined]
                                MAV_STATE_ACTIVE if healthy else MAV_STATE_CRITICAL)


def camera_information(mav: object, time_boot_ms: int, vendor: str, model: str, frame_size: tuple[int, int],
                       geo_status: bool, video_stream: bool = False) -> object:
    """CAMERA_INFORMATION with tracking flags (and HAS_VIDEO_STREAM when the RTP stream is on) and the
    real frame size (0x0 until a frame was seen)."""
    flags = CAMERA_CAP_FLAGS_HAS_TRACKING_POINT | CAMERA_CAP_FLAGS_HAS_TRACKING_RECTANGLE
    if geo_status:
        flags |= CAMERA_CAP_FLAGS_HAS_TRACKING_GEO_STATUS
    if video_stream:
        flags |= CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
    return mav.camera_information_encode(  # type: ignore[attr-defined]
        time_boot_ms, _fixed(vendor, 32), _fixed(model, 32), 0, NAN, NAN, NAN,
        frame_size[0], frame_size[1], 0, flags, 0, b"")


def tracking_image_status(mav: object, status: TrackingStatus) -> object:
    """CAMERA_TRACKING_IMAGE_STATUS (275): point = box centre, radius = half width / image width."""
    if status.box is None:
        return mav.camera_tracking_image_status_encode(  # type: ignore[attr-defined]
            status.status, status.mode, NO_TARGET_DATA, NAN, NAN, NAN, NAN, NAN, NAN, NAN)
    x, y, w, h = status.box
    return mav.camera_tracking_image_status_encode(  # type: ignore[attr-defined]
        status.status, status.mode, CAMERA_TRACKING_TARGET_DATA_IN_STATUS, x + w / 2, y + h / 2, w / 2,
        x, y, x + w, y + h)


def tracking_geo_status(mav: object, status: int, target: GroundTarget | None, vehicle_alt_amsl_m: float | None) -> object:
    """CAMERA_TRACKING_GEO_STATUS (276) from a ground estimate; NaN where unknown.

    Without an estimate (no vehicle position / attitude / gimbal attitude yet, or the ray misses the
    ground) the status is IDLE whatever the image track does: lat / lon are integers with no "unknown"
    value, and ACTIVE with 0, 0 would place the target off the coast of Africa."""
    if target is None:
        return mav.camera_tracking_geo_status_encode(CAMERA_TRACKING_STATUS_FLAGS_IDLE, 0, 0, NAN, NAN, NAN, NAN, NAN, NAN,  # type: ignore[attr-defined]
                                                      NAN, NAN, NAN, NAN)
    dist = math.hypot(target.ground_range_m, (vehicle_alt_amsl_m or target.alt_amsl_m) - target.alt_amsl_m)
    return mav.camera_tracking_geo_status_encode(  # type: ignore[attr-defined]
        status, round(target.lat_deg * 1e7), round(target.lon_deg * 1e7), target.alt_amsl_m,
        NAN, NAN, NAN, NAN, NAN, NAN, dist, NAN, NAN)


def gimbal_rates_ardupilot(mav: object, target: tuple[int, int], device_id: int, yaw_rate: float,
                           pitch_rate: float) -> object:
    """GIMBAL_MANAGER_SET_PITCHYAW (287) as a rate command (rad/s, positive = pitch up / yaw right).

    Per the message's definition NaN means "ignore this field": both angles NaN, both rates finite
    (ArduPilot acts on both rates or both angles, never a mix). flags = YAW_IN_VEHICLE_FRAME: the yaw
    rate is relative to the vehicle's heading, as the image error it comes from; no RETRACT / NEUTRAL
    (which ArduPilot acts on before reading any field) and no YAW_LOCK (earth frame). ValueError on a
    non-finite rate: with NaN rates too the message would ask for nothing.
    """
    if not (math.isfinite(yaw_rate) and math.isfinite(pitch_rate)):
        raise ValueError(f"gimbal rates must be finite, got yaw {yaw_rate}, pitch {pitch_rate}")
    return mav.gimbal_manager_set_pitchyaw_encode(  # type: ignore[attr-defined]
        target[0], target[1], GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME, device_id, NAN, NAN, pitch_rate, yaw_rate)


def gimbal_rates_px4(mav: object, target: tuple[int, int], device_id: int, yaw_rate: float, pitch_rate: float) -> object:
    """GIMBAL_MANAGER_SET_ATTITUDE (282): q NaN, angular velocity (roll NaN, pitch, yaw), yaw in vehicle frame."""
    return mav.gimbal_manager_set_attitude_encode(  # type: ignore[attr-defined]
        target[0], target[1], GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME, device_id, [NAN, NAN, NAN, NAN],
        NAN, pitch_rate, yaw_rate)


def gimbal_claim_px4(mav: object, target: tuple[int, int], own: tuple[int, int], device_id: int) -> object:
    """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (1001): make (own sysid, compid) primary; secondary unchanged (-1)."""
    return mav.command_long_encode(target[0], target[1], MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 0,  # type: ignore[attr-defined]
                                   own[0], own[1], -1, -1, 0, 0, device_id)


def velocity_target(mav: object, target: tuple[int, int], time_boot_ms: int, setpoint: VelocitySetpoint) -> object:
    """SET_POSITION_TARGET_LOCAL_NED (84), velocity + yaw rate only (type_mask 0x05C7), in MAV_FRAME_BODY_NED
    (8): velocity along the vehicle's heading, level. Both autopilots take 8; PX4 refuses
    MAV_FRAME_BODY_OFFSET_NED (9: "coordinate frame 9 unsupported", so OFFBOARD never engaged)."""
    return mav.set_position_target_local_ned_encode(  # type: ignore[attr-defined]
        time_boot_ms, target[0], target[1], MAV_FRAME_BODY_NED, VELOCITY_YAW_RATE_TYPE_MASK,
        0, 0, 0, setpoint.forward, setpoint.right, setpoint.down, 0, 0, 0, 0, setpoint.yaw_rate)


def follow_target(mav: object, timestamp_ms: int, target: GroundTarget) -> object:
    """FOLLOW_TARGET (144) carrying the target's position only (est_capabilities bit 0)."""
    return mav.follow_target_encode(  # type: ignore[attr-defined]
        timestamp_ms, FOLLOW_TARGET_CAP_POSITION, round(target.lat_deg * 1e7), round(target.lon_deg * 1e7),
        target.alt_amsl_m, [0, 0, 0], [0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0, 0, 0], 0)


STATUSTEXT_CHUNK = 50  # bytes of text per STATUSTEXT


def status_texts(mav: object, severity: int, text: str, text_id: int) -> list[object]:
    """STATUSTEXT (253) messages carrying `text` (ASCII): one with id 0 when it fits in 50 bytes, else
    MAVLink 2 chunks under `text_id` (1..65535, chunk_seq from 0) ending with a chunk that holds a NUL."""
    data = text.encode("ascii", "replace")
    if len(data) <= STATUSTEXT_CHUNK:
        return [mav.statustext_encode(severity, data, 0, 0)]  # type: ignore[attr-defined]
    if not 1 <= text_id <= 65535:
        raise ValueError(f"a chunked STATUSTEXT needs an id in 1..65535, got {text_id}")
    chunks = [data[i:i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
    if len(chunks[-1]) == STATUSTEXT_CHUNK:
        chunks.append(b"")  # the last chunk must hold a NUL: an empty one ends a text of whole chunks
    return [mav.statustext_encode(severity, chunk, text_id, seq)  # type: ignore[attr-defined]
            for seq, chunk in enumerate(chunks)]


def _fixed(text: str, size: int) -> list[int]:
    data = text.encode("ascii", "replace")[:size]
    return list(data) + [0] * (size - len(data))
