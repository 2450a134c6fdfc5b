"""The hardware H.264 encoder found at start (service.video.hardware_encoder): V4L2 memory-to-memory nodes
told apart from cameras, decoders and ISPs by fakes of what the probe reads, and the stream's start-up log."""
from __future__ import annotations

import logging
import struct

import pytest

from service.config import StreamConfig
from service.video import rtp_stream
from service.video.hardware_encoder import (V4L2_CAP_DEVICE_CAPS, V4L2_CAP_VIDEO_M2M, V4L2_CAP_VIDEO_M2M_MPLANE,
                                            V4L2_PIX_FMT_H264, V4l2Node, detect_encoder, find_h264_encoder,
                                            is_h264_m2m_encoder, parse_capability, probe_node)
from sim.ports import free_udp_port


def fourcc(code: str) -> int:
    return int.from_bytes(code.encode("ascii"), "little")


CAP_VIDEO_CAPTURE, CAP_STREAMING = 0x1, 0x04000000
# what a Raspberry Pi 4 lists: the camera, then bcm2835-codec's decoder, encoder and ISP (mplane M2M nodes)
CAMERA = V4l2Node("/dev/video0", "uvcvideo", "USB Camera", CAP_VIDEO_CAPTURE | CAP_STREAMING)
DECODER = V4l2Node("/dev/video10", "bcm2835-codec", "bcm2835-codec-decode", V4L2_CAP_VIDEO_M2M_MPLANE | CAP_STREAMING,
                   (fourcc("YU12"), fourcc("YV12"), fourcc("NV12"), fourcc("NV21"), fourcc("RGBP")))
ENCODER = V4l2Node("/dev/video11", "bcm2835-codec", "bcm2835-codec-encode", V4L2_CAP_VIDEO_M2M_MPLANE | CAP_STREAMING,
                   (V4L2_PIX_FMT_H264,))
ISP = V4l2Node("/dev/video12", "bcm2835-codec", "bcm2835-codec-isp", V4L2_CAP_VIDEO_M2M_MPLANE | CAP_STREAMING,
               (fourcc("YU12"), fourcc("NV12"), fourcc("RGB3")))
PI4 = [CAMERA, DECODER, ENCODER, ISP]


def test_the_fourcc_is_v4l2s() -> None:
    assert V4L2_PIX_FMT_H264 == 0x34363248  # v4l2_fourcc('H', '2', '6', '4')


def test_only_a_memory_to_memory_node_with_h264_on_its_capture_queue_is_an_encoder() -> None:
    assert [is_h264_m2m_encoder(node) for node in PI4] == [False, False, True, False]
    uvc_h264_camera = V4l2Node("/dev/video2", "uvcvideo", "H264 webcam", CAP_VIDEO_CAPTURE, (fourcc("H264"),))
    assert not is_h264_m2m_encoder(uvc_h264_camera)  # a camera that sends H.264 encodes nothing for us
    single_plane = V4l2Node("/dev/video3", "vendor-enc", "enc", V4L2_CAP_VIDEO_M2M, (fourcc("NV12"), V4L2_PIX_FMT_H264))
    assert is_h264_m2m_encoder(single_plane)


def test_the_first_encoder_by_device_number_is_found() -> None:
    assert find_h264_encoder(PI4) == ENCODER
    assert find_h264_encoder([CAMERA, DECODER, ISP]) is None
    assert find_h264_encoder([]) is None
    later = V4l2Node("/dev/video31", "other", "enc", V4L2_CAP_VIDEO_M2M_MPLANE, (V4L2_PIX_FMT_H264,))
    early = V4l2Node("/dev/video9", "other", "enc", V4L2_CAP_VIDEO_M2M_MPLANE, (V4L2_PIX_FMT_H264,))
    assert find_h264_encoder([later, ENCODER, early]) == early  # video9 before video11 before video31


def test_the_choice_reports_the_hardware_but_keeps_libx264() -> None:
    found = detect_encoder(lambda: PI4, lambda: True)
    assert found.encoder == "libx264" and found.hardware == ENCODER
    assert found.log_fields() == ("encoder=libx264 hardware_h264=/dev/video11 hardware_driver=bcm2835-codec "
                                  "hardware_used=false ffmpeg_h264_v4l2m2m=true")
    assert detect_encoder(lambda: [CAMERA], lambda: False).log_fields() == (
        "encoder=libx264 hardware_h264=none hardware_used=false ffmpeg_h264_v4l2m2m=false")


def test_querycap_is_read_with_the_nodes_own_capabilities() -> None:
    def capability(capabilities: int, device_caps: int) -> bytes:
        return struct.pack("16s32s32sIII12x", b"bcm2835-codec", b"bcm2835-codec-encode", b"platform:bcm2835-codec",
                           0x060100, capabilities, device_caps)

    own = V4L2_CAP_VIDEO_M2M_MPLANE | CAP_STREAMING
    whole = own | CAP_VIDEO_CAPTURE | V4L2_CAP_DEVICE_CAPS  # what the driver as a whole offers
    assert parse_capability(capability(whole, own)) == ("bcm2835-codec", "bcm2835-codec-encode", own)
    assert parse_capability(capability(own, 0)) == ("bcm2835-codec", "bcm2835-codec-encode", own)  # no DEVICE_CAPS


def test_a_node_that_is_not_v4l2_or_not_there_probes_as_nothing() -> None:
    assert probe_node("/dev/null") is None  # QUERYCAP refused (ENOTTY)
    assert probe_node("/dev/video-no-such-node") is None


def test_the_stream_logs_its_encoder_and_the_hardware_found_at_start(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(rtp_stream, "probe_nodes", lambda: PI4)
    with caplog.at_level(logging.INFO, logger="service.video"):
        stream = rtp_stream.RtpH264Stream(StreamConfig(enabled=True, host="127.0.0.1", port=free_udp_port()), 70.0)
    lines = [record.getMessage() for record in caplog.records if "event=video_encoder" in record.getMessage()]
    assert len(lines) == 1
    assert "encoder=libx264 hardware_h264=/dev/video11 hardware_driver=bcm2835-codec hardware_used=false" in lines[0]
    assert stream.status()["encoder"] == "libx264" and stream.status()["hardware_h264"] == "/dev/video11"


def test_the_stream_encodes_with_libx264_ultrafast_zerolatency_one_thread() -> None:
    options = rtp_stream.x264_options(StreamConfig(fps=30.0, bitrate_kbps=1500, keyframe_interval_s=0.5))
    assert options == {"preset": "ultrafast", "tune": "zerolatency", "threads": "1", "bf": "0", "g": "15",
                       "maxrate": "1500k", "bufsize": "1500k"}
