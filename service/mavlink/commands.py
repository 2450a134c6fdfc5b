"""Camera-component commands (pure): COMMAND_LONG / COMMAND_INT parameters -> validated intent or rejection.

Coordinates are normalised to the image, 0..1, origin top-left, x right, y down. Every command
addressed to the camera gets exactly one Decision: ACCEPTED with an intent, or DENIED /
UNSUPPORTED / FAILED with a reason; a rejected command changes nothing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

from pymavlink.dialects.v20.common import (
    MAV_CMD_CAMERA_STOP_TRACKING, MAV_CMD_CAMERA_TRACK_POINT, MAV_CMD_CAMERA_TRACK_RECTANGLE,
    MAV_CMD_REQUEST_CAMERA_INFORMATION, MAV_CMD_REQUEST_MESSAGE, MAV_CMD_SET_MESSAGE_INTERVAL, MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED,
    MAVLINK_MSG_ID_CAMERA_INFORMATION, MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS, MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS,
    MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, MAV_CMD_REQUEST_VIDEO_STREAM_STATUS, MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
    MAVLINK_MSG_ID_VIDEO_STREAM_STATUS,
)

from service.domain import StopTracking, TrackPoint, TrackRectangle
from service.mavlink.video_stream import VIDEO_STREAM_MESSAGES, stream_id_matches

STREAMABLE_MESSAGES = (MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS)
MIN_INTERVAL_US = 10_000  # 100 Hz: faster than any camera frame rate we serve


@dataclass(frozen=True)
class SetMessageInterval:
    """Stream message_id every interval_s seconds; None = off; "default" = the service's default."""

    message_id: int
    interval_s: float | None | str


@dataclass(frozen=True)
class RequestMessage:
    """Send message_id once."""

    message_id: int


Intent = Union[TrackPoint, TrackRectangle, StopTracking, SetMessageInterval, RequestMessage]


@dataclass(frozen=True)
class Decision:
    """The answer to one command: MAV_RESULT and, when ACCEPTED, what to do."""

    result: int
    reason: str = ""
    intent: Intent | None = None


def command_int_params(param1: float, param2: float, param3: float, param4: float, x: int, y: int,
                       z: float) -> tuple[float, ...]:
    """COMMAND_INT fields -> the seven COMMAND_LONG-style parameters (x, y are plain integers here)."""
    return (param1, param2, param3, param4, float(x), float(y), z)


def is_for_us(target_component: int, command: int, params: tuple[float, ...], own_component: int) -> bool:
    """Whether the camera should answer: addressed to it, or broadcast camera commands meant for all / it."""
    if target_component == own_component:
        return True
    if target_component != 0:
        return False
    camera_id = _camera_id_param(command, params)
    return camera_id is not None and _camera_id_matches(camera_id, own_component)


def decide(command: int, params: tuple[float, ...], own_component: int) -> Decision:
    """Validate one command (seven parameters, COMMAND_LONG numbering) addressed to this camera."""
    if len(params) != 7:
        raise ValueError(f"expected 7 command parameters, got {len(params)}")
    p1, p2, p3, p4, p5, _, _ = params
    camera_id = _camera_id_param(command, params)
    if camera_id is not None and not _camera_id_matches(camera_id, own_component):
        return Decision(MAV_RESULT_DENIED, f"target camera id {camera_id:g} is not this camera "
                                           f"(0 or {own_component})")
    if command == MAV_CMD_CAMERA_TRACK_POINT:
        problem = _check_normalised(x=p1, y=p2)
        if problem:
            return Decision(MAV_RESULT_DENIED, problem)
        if not math.isfinite(p3) or not 0.0 <= p3 <= 1.0:
            return Decision(MAV_RESULT_DENIED, f"radius must be in 0..1 (fraction of image width), got {p3}")
        return Decision(MAV_RESULT_ACCEPTED, intent=TrackPoint(p1, p2, p3))
    if command == MAV_CMD_CAMERA_TRACK_RECTANGLE:
        problem = _check_normalised(top_left_x=p1, top_left_y=p2, bottom_right_x=p3, bottom_right_y=p4)
        if problem:
            return Decision(MAV_RESULT_DENIED, problem)
        if p3 <= p1 or p4 <= p2:
            return Decision(MAV_RESULT_DENIED, f"rectangle ({p1}, {p2})-({p3}, {p4}) is inverted or has zero size")
        return Decision(MAV_RESULT_ACCEPTED, intent=TrackRectangle(p1, p2, p3, p4))
    if command == MAV_CMD_CAMERA_STOP_TRACKING:
        return Decision(MAV_RESULT_ACCEPTED, intent=StopTracking())
    if command == MAV_CMD_SET_MESSAGE_INTERVAL:
        return _decide_interval(p1, p2)
    if command == MAV_CMD_REQUEST_MESSAGE:
        message_id = _as_message_id(p1)
        if message_id is None:
            return Decision(MAV_RESULT_DENIED, f"message id must be a whole number, got {p1}")
        if message_id not in (MAVLINK_MSG_ID_CAMERA_INFORMATION, *STREAMABLE_MESSAGES, *VIDEO_STREAM_MESSAGES):
            return Decision(MAV_RESULT_UNSUPPORTED, f"this camera does not provide message {message_id}")
        if message_id in VIDEO_STREAM_MESSAGES and not stream_id_matches(p2):
            return Decision(MAV_RESULT_DENIED, f"no video stream {p2:g} (this camera has stream 1)")
        return Decision(MAV_RESULT_ACCEPTED, intent=RequestMessage(message_id))
    if command == MAV_CMD_REQUEST_CAMERA_INFORMATION:
        return Decision(MAV_RESULT_ACCEPTED, intent=RequestMessage(MAVLINK_MSG_ID_CAMERA_INFORMATION))
    if command in (MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, MAV_CMD_REQUEST_VIDEO_STREAM_STATUS):  # older ground stations
        if not stream_id_matches(p1):
            return Decision(MAV_RESULT_DENIED, f"no video stream {p1:g} (this camera has stream 1)")
        return Decision(MAV_RESULT_ACCEPTED, intent=RequestMessage(
            MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION if command == MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION
            else MAVLINK_MSG_ID_VIDEO_STREAM_STATUS))
    return Decision(MAV_RESULT_UNSUPPORTED, f"command {command} is not supported by this camera")


def _decide_interval(message_param: float, interval_us: float) -> Decision:
    message_id = _as_message_id(message_param)
    if message_id is None:
        return Decision(MAV_RESULT_DENIED, f"message id must be a whole number, got {message_param}")
    if message_id not in STREAMABLE_MESSAGES:
        return Decision(MAV_RESULT_UNSUPPORTED, f"this camera does not stream message {message_id}")
    if not math.isfinite(interval_us):
        return Decision(MAV_RESULT_DENIED, f"interval must be finite, got {interval_us}")
    if interval_us == -1:
        return Decision(MAV_RESULT_ACCEPTED, intent=SetMessageInterval(message_id, None))
    if interval_us == 0:
        return Decision(MAV_RESULT_ACCEPTED, intent=SetMessageInterval(message_id, "default"))
    if interval_us < MIN_INTERVAL_US:
        return Decision(MAV_RESULT_DENIED, f"interval must be -1, 0 or >= {MIN_INTERVAL_US} us, got {interval_us:g}")
    return Decision(MAV_RESULT_ACCEPTED, intent=SetMessageInterval(message_id, interval_us / 1e6))


def _camera_id_param(command: int, params: tuple[float, ...]) -> float | None:
    """The 'target camera id' parameter of a camera command (NaN / absent = all cameras -> 0)."""
    index = {MAV_CMD_CAMERA_TRACK_POINT: 3, MAV_CMD_CAMERA_TRACK_RECTANGLE: 4, MAV_CMD_CAMERA_STOP_TRACKING: 0}.get(command)
    if index is None:
        return None
    value = params[index]
    # NaN: older ground stations send the then-reserved parameter as NaN, meaning "no particular camera"
    return 0.0 if math.isnan(value) else value


def _camera_id_matches(camera_id: float, own_component: int) -> bool:
    return camera_id == 0 or camera_id == own_component


def _check_normalised(**values: float) -> str | None:
    for name, value in values.items():
        if not math.isfinite(value):
            return f"{name} must be a finite number, got {value}"
        if not 0.0 <= value <= 1.0:
            return f"{name} must be in 0..1 (normalised image coordinate), got {value}"
    return None


def _as_message_id(value: float) -> int | None:
    if not math.isfinite(value) or value != int(value) or value < 0:
        return None
    return int(value)
