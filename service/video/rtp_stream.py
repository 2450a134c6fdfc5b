"""The stream QGroundControl shows: tracked frames as H.264 over RTP/UDP (RFC 6184, payload type 96).

Encoder: libx264 through PyAV (FFmpeg's libraries, bundled in the `av` wheel), preset ultrafast,
tune zerolatency (no frame lookahead, no B-frames: each frame leaves as soon as it is encoded),
one encoder thread, a keyframe every keyframe_interval_s with SPS/PPS repeated in-band, so a
viewer that joins late (QGroundControl started after the drone) shows video from the next
keyframe. FFmpeg's RTP muxer packetises (at most PACKET_SIZE bytes a datagram) and sends RTCP
sender reports to port + 1. Timestamps: the 90 kHz RTP clock from the service's monotonic clock
at frame read, so the played rate follows the camera's real rate, dropped frames included.

Frames are scaled down to fit max_width_px x max_height_px (even sizes, aspect kept, never
enlarged) and converted to 4:2:0 with OpenCV; all of it on the worker's thread
(service.video.latest_frame_worker), never on the loop's. A change of frame size re-opens the
encoder (a new SPS; RTP receivers follow it).
"""
from __future__ import annotations

import fractions
import logging
import socket
import time

import cv2
import numpy as np

from service.config import ConfigError, StreamConfig
from service.mavlink.video_stream import VideoStreamDescription
from service.sources.base import Frame
from service.video.hardware_encoder import detect_encoder, probe_nodes
from service.video.latest_frame_worker import LatestFrameWorker, WorkerOutput, fit_size

log = logging.getLogger("service.video")
RTP_CLOCK_HZ = 90_000  # the RTP clock of H.264 video (RFC 6184)
PACKET_SIZE = 1200  # bytes per UDP datagram: below the 1500-byte Ethernet MTU with room for VPN / radio headers
RUNNING_WITHIN_S = 2.0  # the stream counts as running while a frame was sent this recently


def rtp_url(host: str, port: int) -> str:
    """FFmpeg URL of the RTP destination (RTCP goes to port + 1)."""
    return f"rtp://{host}:{port}?pkt_size={PACKET_SIZE}"


def check_destination(config: StreamConfig) -> None:
    """ConfigError naming video.stream.host when it does not resolve to an IPv4 address."""
    try:
        socket.getaddrinfo(config.host, config.port, socket.AF_INET, socket.SOCK_DGRAM)
    except OSError as exc:
        raise ConfigError(f"video.stream.host: cannot resolve {config.host!r}: {exc}") from exc


def yuv420(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """BGR (HxWx3) or grey (HxW) uint8 -> I420 planes (H*3/2 x W uint8) at size (width, height), even."""
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if (image.shape[1], image.shape[0]) != size:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(image, cv2.COLOR_BGR2YUV_I420)


def x264_options(config: StreamConfig) -> dict[str, str]:
    """libx264's options for the stream: ultrafast + zerolatency (the cheapest preset; no lookahead, no B-frames),
    one thread, a keyframe every keyframe_interval_s, bit rate capped at bitrate_kbps with a one-second VBV."""
    return {"preset": "ultrafast", "tune": "zerolatency", "threads": "1", "bf": "0",
            "g": str(max(1, round(config.keyframe_interval_s * config.fps))),
            "maxrate": f"{config.bitrate_kbps}k", "bufsize": f"{config.bitrate_kbps}k"}


def h264_encoder_library():  # -> the av module
    """PyAV, checked to have the libx264 encoder; ConfigError naming video.stream.enabled otherwise (some
    wheels, e.g. PyAV's armv7l builds, ship FFmpeg without libx264)."""
    try:
        import av  # imported only when the stream is on: the rest of the service runs without it
        av.codec.Codec("libx264", "w")
    except ImportError as exc:
        raise ConfigError(f"video.stream.enabled: the H.264 stream needs PyAV (pip package av): {exc}") from exc
    except ValueError as exc:  # av.codec.codec.UnknownCodecError
        raise ConfigError("video.stream.enabled: this PyAV build has no libx264 H.264 encoder "
                          f"({type(exc).__name__}: {exc}); install a PyAV wheel with libx264 or switch the stream off") from exc
    return av


def has_encoder(av, name: str) -> bool:  # av: the PyAV module
    """Whether this PyAV build has the FFmpeg encoder `name`."""
    try:
        av.codec.Codec(name, "w")
    except ValueError:  # av.codec.codec.UnknownCodecError
        return False
    return True


class RtpH264Stream(WorkerOutput):
    """Sends the newest tracked frame as H.264 over RTP/UDP to config.host:config.port, at most fps a second."""

    def __init__(self, config: StreamConfig, hfov_deg: float) -> None:
        """ConfigError naming video.stream.enabled when PyAV or its libx264 encoder is missing."""
        self._av = h264_encoder_library()
        # a hardware encoder (the Pi 4's V4L2 memory-to-memory one) is reported at start, not used: docs/results-cost.md
        self.encoder = detect_encoder(probe_nodes, lambda: has_encoder(self._av, "h264_v4l2m2m"))
        log.info("event=video_encoder %s", self.encoder.log_fields())
        self.config = config
        self.hfov_deg = hfov_deg
        self.url = rtp_url(config.host, config.port)
        self.worker = LatestFrameWorker("stream", self._send, config.fps, close=self._close)
        self._container = None
        self._stream = None
        self._size: tuple[int, int] | None = None  # encoded (width, height) px
        self._clock_origin_s: float | None = None
        self._last_pts = -1
        self._last_sent_s: float | None = None
        self.encoder_opens = 0

    # --- the worker's thread ------------------------------------------------------------------
    def _open(self, size: tuple[int, int]) -> None:
        av = self._av
        cfg = self.config
        container = av.open(self.url, mode="w", format="rtp")
        try:
            stream = container.add_stream("libx264", rate=fractions.Fraction(cfg.fps).limit_denominator(1001))
            stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
            stream.bit_rate = cfg.bitrate_kbps * 1000
            stream.codec_context.time_base = fractions.Fraction(1, RTP_CLOCK_HZ)
            stream.codec_context.options = x264_options(cfg)
        except Exception:
            container.close()
            raise
        self._container, self._stream, self._size = container, stream, size
        self.encoder_opens += 1
        log.info("event=video_stream_open url=%s size=%dx%d fps=%.1f bitrate_kbps=%d", self.url, size[0], size[1],
                 cfg.fps, cfg.bitrate_kbps)

    def _send(self, frame: Frame) -> None:
        image = frame.image
        size = fit_size((image.shape[1], image.shape[0]), (self.config.max_width_px, self.config.max_height_px),
                        even=True)
        if self._container is None or size != self._size:
            self._close()
            self._open(size)
        if self._clock_origin_s is None:
            self._clock_origin_s = frame.read_monotonic_s
        pts = max(round((frame.read_monotonic_s - self._clock_origin_s) * RTP_CLOCK_HZ), self._last_pts + 1)
        video_frame = self._av.VideoFrame.from_ndarray(yuv420(image, size), format="yuv420p")
        video_frame.pts = pts
        video_frame.time_base = fractions.Fraction(1, RTP_CLOCK_HZ)
        try:
            for packet in self._stream.encode(video_frame):  # type: ignore[union-attr]
                self._container.mux(packet)  # type: ignore[union-attr]
        except Exception:
            self._close()  # re-opened (new keyframe, SPS / PPS) on the next frame
            raise
        self._last_pts = pts
        self._last_sent_s = time.monotonic()

    def _close(self) -> None:
        container, self._container, self._stream = self._container, None, None
        if container is not None:
            try:
                container.close()
            except Exception as exc:  # noqa: BLE001 - the socket may be gone already
                log.debug('event=video_stream_close_failed error="%s"', exc)

    # --- any thread ---------------------------------------------------------------------------
    def running(self) -> bool:
        """A frame went out within the last RUNNING_WITHIN_S seconds."""
        last = self._last_sent_s
        return last is not None and time.monotonic() - last < RUNNING_WITHIN_S

    def describe(self, frame_size: tuple[int, int] | None) -> VideoStreamDescription | None:
        """The stream as announced over MAVLink, for camera frames of frame_size (None until one arrived)."""
        if frame_size is None:
            return None
        cfg = self.config
        return VideoStreamDescription(
            port=cfg.port, size=fit_size(frame_size, (cfg.max_width_px, cfg.max_height_px), even=True),
            fps=cfg.fps, bitrate_bps=cfg.bitrate_kbps * 1000, hfov_deg=self.hfov_deg, running=self.running())

    def status(self) -> dict[str, object]:
        hardware = self.encoder.hardware
        return {"url": self.url, "running": self.running(), "size": list(self._size) if self._size else None,
                "encoder": self.encoder.encoder, "hardware_h264": hardware.path if hardware else None,
                "encoder_opens": self.encoder_opens, **self.worker.counters()}
