"""The daemon's preview frames (`<prefix>/camera/preview`), decoded from their documented wire format.

One Zenoh sample per frame: a 32-byte little-endian header, then a JPEG stream (docs/video.md):

    offset size  field
    0      4     magic b"JFR1"
    4      4     pixel format b"JPEG"
    8      4     width  (uint32, pixels of the JPEG)
    12     4     height (uint32, pixels of the JPEG)
    16     8     frame id (uint64): the `frame_id` of this frame's `<prefix>/track` sample
    24     8     capture time (float64, seconds): that sample's `capture_time`
    32     ...   JPEG stream

Written from the format, not from the service's code (the ground side imports none of it). The JPEG
itself is not decoded here: the browser decodes it; the header and the JPEG's start and end markers
are checked so a malformed sample is refused before it reaches a page.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

PREVIEW_SUFFIX = "camera/preview"  # under a drone's key prefix
MAGIC = b"JFR1"
JPEG_FORMAT = b"JPEG"
HEADER = struct.Struct("<4s4sIIQd")  # magic, pixel format, width, height, frame id, capture time
JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"


@dataclass(frozen=True)
class PreviewFrame:
    """One preview frame: JPEG size in pixels, the tracked frame's id and capture time (s), the JPEG bytes."""

    width: int
    height: int
    frame_id: int
    capture_time: float
    jpeg: bytes


def decode_preview(payload: bytes) -> PreviewFrame:
    """Parse one preview sample; ValueError naming the problem (short, bad magic, not JPEG, empty size,
    no JPEG start / end marker)."""
    if len(payload) < HEADER.size + len(JPEG_START) + len(JPEG_END):
        raise ValueError(f"preview sample too short: {len(payload)} bytes")
    magic, pixel_format, width, height, frame_id, capture_time = HEADER.unpack_from(payload, 0)
    if magic != MAGIC:
        raise ValueError(f"bad preview magic {magic!r} (expected {MAGIC!r})")
    if pixel_format != JPEG_FORMAT:
        raise ValueError(f"preview pixel format {pixel_format!r} is not {JPEG_FORMAT!r}")
    if width == 0 or height == 0:
        raise ValueError(f"preview size {width}x{height} is empty")
    jpeg = payload[HEADER.size:]
    if not jpeg.startswith(JPEG_START):
        raise ValueError("preview data does not start with a JPEG start-of-image marker")
    if not jpeg.rstrip(b"\x00").endswith(JPEG_END):
        raise ValueError("preview data does not end with a JPEG end-of-image marker (truncated?)")
    return PreviewFrame(width, height, frame_id, capture_time, bytes(jpeg))


def drone_prefix(key: str, suffix: str) -> str | None:
    """The drone's key prefix of `key` = `<prefix>/<suffix>`, None if key does not end so (or has no prefix)."""
    tail = "/" + suffix
    if not key.endswith(tail) or len(key) == len(tail):
        return None
    return key[:-len(tail)]
