"""Wire format of camera frames published over Zenoh (sim harness -> service).

One Zenoh sample per frame: a 32-byte little-endian header followed by the pixel data.

    offset size  field
    0      4     magic b"JFR1"
    4      4     pixel format: b"BGR3" (raw bgr24), b"GRAY" (raw 8-bit), b"JPEG" (JPEG bytes)
    8      4     width  (uint32, pixels)
    12     4     height (uint32, pixels)
    16     8     frame id (uint64, increasing per publisher)
    24     8     capture timestamp (float64, seconds, publisher's clock.time())
    32     ...   data: width*height*3 bytes (BGR3), width*height (GRAY), or a JPEG stream
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import cv2
import numpy as np

from service.sources.base import is_complete_jpeg

MAGIC = b"JFR1"
HEADER = struct.Struct("<4s4sIIQd")
PIXEL_FORMATS = (b"BGR3", b"GRAY", b"JPEG")
# The largest frame side taken: 4K (3840x2160, DCI 4096x2160) fits; a 4096x4096 BGR frame is 48 MB. A JPEG's
# size is in its own header and the decoder allocates it before reading the data: a 1 kB payload claiming
# 30000x30000 took 5.2 GB and 31 s to decode (bench.fuzz zenoh, jpeg_bomb), so the size is checked first.
MAX_SIDE_PX = 4096
# JPEG start-of-frame markers (SOF0..SOF15 but DHT C4, JPG C8, DAC CC): height and width follow their length
JPEG_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


@dataclass(frozen=True)
class WireFrame:
    """A decoded frame: image HxWx3 (BGR) or HxW (grey) uint8, frame id, capture time in seconds."""

    image: np.ndarray
    frame_id: int
    timestamp: float


def encode_frame(image: np.ndarray, frame_id: int, timestamp: float, pixel_format: bytes = b"BGR3",
                 jpeg_quality: int = 90) -> bytes:
    """Serialise a uint8 BGR (HxWx3) or grey (HxW) image into one Zenoh payload."""
    if image.dtype != np.uint8:
        raise ValueError(f"frame must be uint8, got {image.dtype}")
    height, width = image.shape[:2]
    if pixel_format == b"BGR3":
        if image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"BGR3 needs an HxWx3 image, got shape {image.shape}")
        data = np.ascontiguousarray(image).tobytes()
    elif pixel_format == b"GRAY":
        if image.ndim != 2:
            raise ValueError(f"GRAY needs an HxW image, got shape {image.shape}")
        data = np.ascontiguousarray(image).tobytes()
    elif pixel_format == b"JPEG":
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise ValueError("JPEG encoding failed")
        data = buf.tobytes()
    else:
        raise ValueError(f"unknown pixel format {pixel_format!r}; expected one of {PIXEL_FORMATS}")
    return HEADER.pack(MAGIC, pixel_format, width, height, int(frame_id), float(timestamp)) + data


def jpeg_size(data: bytes | bytearray | memoryview) -> tuple[int, int] | None:
    """(width, height) in pixels from a JPEG stream's frame header (SOFn), read without decoding; None when the
    stream has no frame header before its scan data (not a JPEG, or a corrupt one)."""
    view = memoryview(data)
    if len(view) < 4 or view[0] != 0xFF or view[1] != 0xD8:
        return None
    at = 2
    while at + 4 <= len(view):
        if view[at] != 0xFF:
            return None
        marker = view[at + 1]
        if marker == 0xFF:  # fill byte before a marker
            at += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            at += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan before any frame header
            return None
        length = view[at + 2] << 8 | view[at + 3]
        if marker in JPEG_SOF_MARKERS:
            if at + 9 > len(view):
                return None
            return view[at + 7] << 8 | view[at + 8], view[at + 5] << 8 | view[at + 6]
        at += 2 + length
    return None


def decode_frame(payload: bytes | bytearray | memoryview) -> WireFrame:
    """Parse one payload; ValueError on a bad magic, unknown format, size mismatch or corrupt JPEG."""
    view = memoryview(payload)
    if len(view) < HEADER.size:
        raise ValueError(f"frame payload too short: {len(view)} bytes")
    magic, pixel_format, width, height, frame_id, timestamp = HEADER.unpack_from(view, 0)
    if magic != MAGIC:
        raise ValueError(f"bad frame magic {magic!r}")
    if width == 0 or height == 0:
        raise ValueError(f"frame size {width}x{height} is empty")
    if width > MAX_SIDE_PX or height > MAX_SIDE_PX:
        raise ValueError(f"frame size {width}x{height} exceeds {MAX_SIDE_PX} px a side")
    data = view[HEADER.size:]
    if pixel_format in (b"BGR3", b"GRAY"):
        channels = 3 if pixel_format == b"BGR3" else 1
        expected = width * height * channels
        if len(data) != expected:
            raise ValueError(f"{pixel_format.decode()} {width}x{height} needs {expected} bytes, got {len(data)}")
        image = np.frombuffer(data, dtype=np.uint8)
        image = image.reshape((height, width, 3) if channels == 3 else (height, width))
    elif pixel_format == b"JPEG":
        if not is_complete_jpeg(data):
            raise ValueError("truncated JPEG frame (no end-of-image marker)")
        size = jpeg_size(data)
        if size is None:
            raise ValueError("corrupt JPEG frame (no frame header)")
        if size != (width, height):  # checked before decoding: the decoder allocates what the JPEG claims
            raise ValueError(f"JPEG is {size[0]}x{size[1]}, header says {width}x{height}")
        try:
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        except cv2.error as exc:  # OpenCV's own limits and assertions on odd streams
            raise ValueError(f"corrupt JPEG frame: {str(exc).strip().splitlines()[-1]}") from exc
        if image is None:
            raise ValueError("corrupt JPEG frame")
        if image.shape[:2] != (height, width):
            raise ValueError(f"JPEG is {image.shape[1]}x{image.shape[0]}, header says {width}x{height}")
    else:
        raise ValueError(f"unknown pixel format {pixel_format!r}")
    return WireFrame(image=image, frame_id=frame_id, timestamp=timestamp)
