"""MAVLink builders (pure) for the camera's video stream: VIDEO_STREAM_INFORMATION (269) and
VIDEO_STREAM_STATUS (270), with pymavlink's enums.

One stream, id 1: H.264 over RTP/UDP. Its `uri` is the UDP port number the ground station listens
on, as the message definition asks for RTP/UDP ("port number (UDP port ground station should listen
to)"); QGroundControl turns it into `udp://0.0.0.0:<port>`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

STREAM_ID = 1
STREAM_COUNT = 1
STREAM_NAME = "tracked camera"
VIDEO_STREAM_MESSAGES = (mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS)


@dataclass(frozen=True)
class VideoStreamDescription:
    """The stream as announced: UDP port, encoded size (width, height) px, frame rate (Hz, the configured
    maximum), bit rate (bits/s, the encoder's target), horizontal field of view (degrees), running (frames
    are going out)."""

    port: int
    size: tuple[int, int]
    fps: float
    bitrate_bps: int
    hfov_deg: float
    running: bool


def _flags(stream: VideoStreamDescription) -> int:
    return mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING if stream.running else 0


def video_stream_information(mav: object, stream: VideoStreamDescription) -> object:
    """VIDEO_STREAM_INFORMATION (269): RTP/UDP, H.264, uri = the UDP port."""
    return mav.video_stream_information_encode(  # type: ignore[attr-defined]
        STREAM_ID, STREAM_COUNT, mavlink.VIDEO_STREAM_TYPE_RTPUDP, _flags(stream), stream.fps,
        stream.size[0], stream.size[1], stream.bitrate_bps, 0, round(stream.hfov_deg),
        STREAM_NAME.encode("ascii"), str(stream.port).encode("ascii"), mavlink.VIDEO_STREAM_ENCODING_H264)


def video_stream_status(mav: object, stream: VideoStreamDescription) -> object:
    """VIDEO_STREAM_STATUS (270): running flag, frame rate, size, bit rate, field of view."""
    return mav.video_stream_status_encode(  # type: ignore[attr-defined]
        STREAM_ID, _flags(stream), stream.fps, stream.size[0], stream.size[1], stream.bitrate_bps, 0,
        round(stream.hfov_deg))


def stream_id_matches(stream_id: float) -> bool:
    """A requested stream id this camera serves: 0 (all) or ours; NaN (parameter unused) = all."""
    return stream_id != stream_id or stream_id in (0, STREAM_ID)
