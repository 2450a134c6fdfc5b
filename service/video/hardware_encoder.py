"""Finds a hardware H.264 encoder at start: a V4L2 memory-to-memory device that outputs H.264.

On a Raspberry Pi 4 that is /dev/video11 (driver bcm2835-codec); other boards have their own (Rockchip,
Amlogic, ...). The same interface everywhere: VIDIOC_QUERYCAP says memory-to-memory, and VIDIOC_ENUM_FMT
lists H.264 among the formats of its capture queue (an encoder's output; a decoder lists it on the
output queue). The stream does not use it yet (docs/results-cost.md, "The service's own work per frame"):
the service logs what it found, so an integrator knows the route is there.
"""
from __future__ import annotations

import fcntl
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

# linux/videodev2.h
V4L2_CAP_VIDEO_M2M_MPLANE = 0x00004000
V4L2_CAP_VIDEO_M2M = 0x00008000
V4L2_CAP_DEVICE_CAPS = 0x80000000  # device_caps is filled in: the node's own capabilities
BUF_TYPE_VIDEO_CAPTURE = 1
BUF_TYPE_VIDEO_CAPTURE_MPLANE = 9
V4L2_PIX_FMT_H264 = int.from_bytes(b"H264", "little")  # v4l2_fourcc('H', '2', '6', '4')
# struct v4l2_capability: driver[16] card[32] bus_info[32] version capabilities device_caps reserved[3]
CAPABILITY_SIZE = 104
FMTDESC_SIZE = 64  # struct v4l2_fmtdesc: index type flags description[32] pixelformat mbus_code reserved[3]
MAX_FORMATS = 64  # a guard against a driver that never ends the enumeration


def ioctl_request(direction: int, number: int, size: int) -> int:
    """Linux's _IOC('V', number, size) request number; direction 2 = the kernel writes, 3 = both ways."""
    return (direction << 30) | (size << 16) | (ord("V") << 8) | number


VIDIOC_QUERYCAP = ioctl_request(2, 0, CAPABILITY_SIZE)  # _IOR('V', 0, struct v4l2_capability)
VIDIOC_ENUM_FMT = ioctl_request(3, 2, FMTDESC_SIZE)  # _IOWR('V', 2, struct v4l2_fmtdesc)


@dataclass(frozen=True)
class V4l2Node:
    """What the probe learnt of one /dev/video* node: driver, card, capability bits, capture-queue fourccs."""

    path: str
    driver: str
    card: str
    capabilities: int  # the node's own (device_caps when the driver fills it in)
    capture_formats: tuple[int, ...] = ()


@dataclass(frozen=True)
class EncoderChoice:
    """The stream's encoder and the hardware H.264 encoder found (None: none)."""

    encoder: str
    hardware: V4l2Node | None
    ffmpeg_has_v4l2m2m: bool

    def log_fields(self) -> str:
        """`key=value` fields of the event=video_encoder log line."""
        found = f"{self.hardware.path}" if self.hardware else "none"
        driver = f" hardware_driver={self.hardware.driver}" if self.hardware else ""
        return (f"encoder={self.encoder} hardware_h264={found}{driver} hardware_used=false "
                f"ffmpeg_h264_v4l2m2m={str(self.ffmpeg_has_v4l2m2m).lower()}")


def is_h264_m2m_encoder(node: V4l2Node) -> bool:
    """A memory-to-memory node whose capture queue (the encoded side) offers H.264."""
    m2m = node.capabilities & (V4L2_CAP_VIDEO_M2M | V4L2_CAP_VIDEO_M2M_MPLANE)
    return bool(m2m) and V4L2_PIX_FMT_H264 in node.capture_formats


def find_h264_encoder(nodes: Iterable[V4l2Node]) -> V4l2Node | None:
    """The first H.264 memory-to-memory encoder among `nodes`, by path order; None when there is none."""
    return min((node for node in nodes if is_h264_m2m_encoder(node)), key=lambda node: video_index(node.path),
               default=None)


def video_index(path: str) -> tuple[int, str]:
    """Sort key of a /dev/videoN path: by N (video2 before video11), then by name."""
    suffix = Path(path).name.removeprefix("video")
    return (int(suffix), path) if suffix.isdigit() else (1 << 30, path)


def choose_encoder(hardware: V4l2Node | None, ffmpeg_has_v4l2m2m: bool) -> EncoderChoice:
    """libx264 always: the hardware route is reported, not taken (FFmpeg's h264_v4l2m2m is untested on a board,
    and the Pi 4's encoder repeats SPS / PPS with keyframes only when asked, which late viewers need)."""
    return EncoderChoice("libx264", hardware, ffmpeg_has_v4l2m2m)


# --- probing (the OS) ----------------------------------------------------------------------------
def _c_string(raw: bytes) -> str:
    """A NUL-terminated ASCII field as text."""
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def parse_capability(raw: bytes) -> tuple[str, str, int]:
    """(driver, card, the node's capability bits) of a struct v4l2_capability."""
    driver, card, _bus, _version, capabilities, device_caps = struct.unpack_from("16s32s32sIII", raw)
    own = device_caps if capabilities & V4L2_CAP_DEVICE_CAPS else capabilities
    return _c_string(driver), _c_string(card), own


def _ioctl(fd: int, request: int, buffer: bytearray) -> bool:
    """The ioctl on `buffer` (filled in place); False when the driver refused it."""
    try:
        fcntl.ioctl(fd, request, buffer, True)
    except OSError:
        return False
    return True


def _capture_formats(fd: int, buffer_type: int) -> tuple[int, ...]:
    """The fourccs VIDIOC_ENUM_FMT lists for buffer_type."""
    formats = []
    for index in range(MAX_FORMATS):
        desc = bytearray(FMTDESC_SIZE)
        struct.pack_into("II", desc, 0, index, buffer_type)
        if not _ioctl(fd, VIDIOC_ENUM_FMT, desc):
            break  # EINVAL ends the list
        formats.append(struct.unpack_from("I", desc, 44)[0])  # pixelformat after index, type, flags, description
    return tuple(formats)


def probe_node(path: str) -> V4l2Node | None:
    """QUERYCAP and the capture queue's formats of one node; None when it cannot be opened or is not V4L2."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        caps = bytearray(CAPABILITY_SIZE)
        if not _ioctl(fd, VIDIOC_QUERYCAP, caps):
            return None
        driver, card, own = parse_capability(bytes(caps))
        kind = BUF_TYPE_VIDEO_CAPTURE_MPLANE if own & V4L2_CAP_VIDEO_M2M_MPLANE else BUF_TYPE_VIDEO_CAPTURE
        formats = _capture_formats(fd, kind) if own & (V4L2_CAP_VIDEO_M2M | V4L2_CAP_VIDEO_M2M_MPLANE) else ()
        return V4l2Node(path, driver, card, own, formats)
    finally:
        os.close(fd)


def probe_nodes(dev: Path = Path("/dev")) -> list[V4l2Node]:
    """Every /dev/video* node that answers QUERYCAP."""
    nodes = (probe_node(str(path)) for path in sorted(dev.glob("video*")))
    return [node for node in nodes if node is not None]


def detect_encoder(probe: Callable[[], list[V4l2Node]] = probe_nodes,
                   ffmpeg_has_v4l2m2m: Callable[[], bool] = lambda: False) -> EncoderChoice:
    """The stream's encoder choice from a probe of the V4L2 nodes and of FFmpeg's h264_v4l2m2m encoder."""
    return choose_encoder(find_h264_encoder(probe()), ffmpeg_has_v4l2m2m())
