"""The H.264 RTP/UDP stream: decoded by Debian's ffmpeg (a decoder that is not ours), and announced over
MAVLink (CAMERA_INFORMATION's HAS_VIDEO_STREAM flag, VIDEO_STREAM_INFORMATION / VIDEO_STREAM_STATUS)."""
from __future__ import annotations

import math
import re
import shutil
import socket
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from pymavlink.dialects.v20 import common as mavlink
from service.app import Service
from service.config import ConfigError
from service.mavlink.commands import MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, RequestMessage, decide
from sim.ports import free_udp_port
from tests.service_peers import RunningService, service_config
from tests.test_service_mavlink import AP_SYSID, CAM, REQUEST, Rig
from tests.test_service_sources import scene

WAIT_S = 20.0
UNSUPPORTED = 3
FRAMES_DECODED = 24


def free_udp_port_pair() -> int:
    """An even loopback UDP port p with p + 1 free too (RTP on p, RTCP on p + 1)."""
    for _ in range(50):
        port = free_udp_port()
        if port % 2 or port >= 65535:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rtcp:
            try:
                rtcp.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
            return port
    raise RuntimeError("no free pair of UDP ports")


@pytest.fixture(scope="module")
def vga_frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("stream_frames")
    for i in range(30):
        cv2.imwrite(str(folder / f"{i:04d}.png"), scene((640, 480), (150 + 10 * i, 240), 80))
    return folder


def coarse_grey(image: np.ndarray) -> np.ndarray:
    """A 32x24 grey thumbnail (int), to compare pictures through lossy coding."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.resize(grey, (32, 24), interpolation=cv2.INTER_AREA).astype(int)


# --- decoded by ffmpeg ---------------------------------------------------------------------------
def test_ffmpeg_decodes_the_rtp_h264_stream_at_the_configured_size(vga_frames: Path, tmp_path: Path) -> None:
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        pytest.skip("ffmpeg is not installed (Debian: apt-get install -y ffmpeg; .ci/run installs it)")
    port = free_udp_port_pair()
    sdp = tmp_path / "stream.sdp"  # what a receiver needs to know about the stream: RTP/AVP 96, H.264
    sdp.write_text("v=0\no=- 0 0 IN IP4 127.0.0.1\ns=jsar\nc=IN IP4 127.0.0.1\nt=0 0\n"
                   f"m=video {port} RTP/AVP 96\na=rtpmap:96 H264/90000\na=fmtp:96 packetization-mode=1\n")
    width, height = 320, 240  # 640x480 frames scaled down to fit
    receiver = subprocess.Popen(
        [ffmpeg, "-nostdin", "-hide_banner", "-loglevel", "info", "-protocol_whitelist", "file,udp,rtp",
         "-i", str(sdp), "-frames:v", str(FRAMES_DECODED), "-fps_mode", "passthrough",
         "-f", "rawvideo", "-pix_fmt", "gray", "-"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    config = service_config(free_udp_port(), {
        "source": {"path": str(vga_frames), "loop": True, "fps": 30.0},
        "video": {"stream": {"enabled": True, "host": "127.0.0.1", "port": port, "max_width_px": width,
                             "max_height_px": 400, "fps": 30.0, "bitrate_kbps": 800,
                             "keyframe_interval_s": 0.5}},
    })
    running = RunningService(Service(config)).start()
    try:
        # the daemon streams continuously; ffmpeg joins at the next keyframe and stops after FRAMES_DECODED
        out, err = receiver.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        receiver.kill()
        out, err = receiver.communicate()
        pytest.fail(f"ffmpeg decoded {len(out) // (width * height)} frames in 60 s:\n{err.decode()[-3000:]}")
    finally:
        running.stop()
    log = err.decode()
    assert receiver.returncode == 0, log[-3000:]
    assert re.search(rf"Video: h264 .*{width}x{height}", log), log[-3000:]
    assert len(out) == FRAMES_DECODED * width * height  # exactly the frames asked for, each width x height
    decoded = np.frombuffer(out, np.uint8).reshape(FRAMES_DECODED, height, width)
    sources = [coarse_grey(cv2.resize(cv2.imread(str(p)), (width, height), interpolation=cv2.INTER_AREA))
               for p in sorted(vga_frames.glob("*.png"))]
    for frame in decoded:  # each decoded frame is one of the tracked frames, through H.264
        errors = [np.abs(coarse_grey(frame) - s).mean() for s in sources]
        assert min(errors) < 4.0, f"a decoded frame matches no source frame (best mean error {min(errors):.1f})"
    stream = running.service.stream  # type: ignore[attr-defined]
    assert stream.worker.errors == 0 and stream.worker.sent >= FRAMES_DECODED


def test_an_unresolvable_stream_host_stops_the_service_naming_the_key() -> None:
    config = service_config(free_udp_port(), {
        "source": {"path": "unused"},
        "video": {"stream": {"enabled": True, "host": "no-such-host.invalid"}},
    })
    with pytest.raises(ConfigError, match="video.stream.host: cannot resolve 'no-such-host.invalid'"):
        Service(config)


def test_a_pyav_without_libx264_stops_the_service_naming_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    import av

    from service.video.rtp_stream import h264_encoder_library

    def no_x264(name: str, mode: str = "r") -> None:
        raise av.codec.codec.UnknownCodecError(name)  # as on PyAV's armv7l wheels

    monkeypatch.setattr(av.codec, "Codec", no_x264)
    with pytest.raises(ConfigError, match="video.stream.enabled: this PyAV build has no libx264 H.264 encoder"):
        h264_encoder_library()


# --- announced over MAVLink ----------------------------------------------------------------------
def test_video_stream_requests_decide_with_pymavlink_ids() -> None:
    info, status = mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS
    nan = math.nan
    for message in (info, status):
        for stream_id in (0, 1, nan):
            decision = decide(mavlink.MAV_CMD_REQUEST_MESSAGE, (message, stream_id, 0, 0, 0, 0, 0), 100)
            assert decision.result == MAV_RESULT_ACCEPTED and decision.intent == RequestMessage(message)
        assert decide(mavlink.MAV_CMD_REQUEST_MESSAGE, (message, 2, 0, 0, 0, 0, 0), 100).result == MAV_RESULT_DENIED
    legacy = decide(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, (0, 0, 0, 0, 0, 0, 0), 100)
    assert legacy.intent == RequestMessage(info)
    assert decide(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS, (1, 0, 0, 0, 0, 0, 0), 100).intent == RequestMessage(status)
    assert decide(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS, (3, 0, 0, 0, 0, 0, 0), 100).result == MAV_RESULT_DENIED


def camera_information(rig: Rig) -> object:
    """CAMERA_INFORMATION as answered to MAV_CMD_REQUEST_MESSAGE under the autopilot's system id."""
    assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, WAIT_S)
    result, info = request(rig, mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION, "CAMERA_INFORMATION")
    assert result == MAV_RESULT_ACCEPTED and info.get_srcSystem() == AP_SYSID
    return info


def request(rig: Rig, message_id: int, kind: str) -> tuple[int, object | None]:
    """Send MAV_CMD_REQUEST_MESSAGE for message_id; (ACK result, the message answered or None)."""
    acks, before = rig.gcs.ack_count(REQUEST), len(rig.gcs.received.of(kind))
    rig.gcs.command_long(REQUEST, [message_id, 0, 0, 0, 0, 0, 0], target=CAM)
    ack = rig.gcs.wait_ack(REQUEST, acks, WAIT_S)
    assert ack is not None, f"no ACK for the request of {kind}"
    if ack.result != MAV_RESULT_ACCEPTED:
        return ack.result, None
    assert rig.gcs.received.wait_for(lambda: len(rig.gcs.received.of(kind)) > before, WAIT_S), f"no {kind}"
    return ack.result, rig.gcs.received.of(kind)[-1].msg


def test_camera_announces_the_rtp_stream_and_answers_video_stream_requests(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(10):
        cv2.imwrite(str(frames / f"{i:04d}.png"), scene((160, 120), (60 + i, 40), 20))
    port = free_udp_port_pair()  # nobody listens: UDP is fire-and-forget, the stream runs all the same
    rig = Rig({"source": {"path": str(frames), "loop": True},
               "camera": {"hfov_deg": 62.0},
               "video": {"stream": {"enabled": True, "host": "127.0.0.1", "port": port, "fps": 25.0,
                                    "bitrate_kbps": 1500}}})
    try:
        assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", WAIT_S)
        info = camera_information(rig)
        assert info.flags & mavlink.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        assert info.flags & mavlink.CAMERA_CAP_FLAGS_HAS_TRACKING_POINT
        stream = rig.service.stream
        assert stream.worker.wait_until(lambda: stream.worker.sent >= 3, WAIT_S)
        result, msg = request(rig, mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, "VIDEO_STREAM_INFORMATION")
        assert result == MAV_RESULT_ACCEPTED
        assert msg.get_srcSystem() == AP_SYSID and msg.get_srcComponent() == 100
        assert (msg.stream_id, msg.count) == (1, 1)
        assert msg.type == mavlink.VIDEO_STREAM_TYPE_RTPUDP
        assert msg.encoding == mavlink.VIDEO_STREAM_ENCODING_H264
        assert msg.uri == str(port)  # RTP/UDP: the port the ground station listens on
        assert (msg.resolution_h, msg.resolution_v) == (160, 120)  # the frames' size (fits 640x480)
        assert msg.framerate == pytest.approx(25.0) and msg.bitrate == 1_500_000 and msg.hfov == 62
        assert msg.flags & mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING
        assert msg.name == "tracked camera"
        result, status = request(rig, mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS, "VIDEO_STREAM_STATUS")
        assert result == MAV_RESULT_ACCEPTED
        assert status.stream_id == 1 and status.flags & mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING
        assert (status.resolution_h, status.resolution_v, status.bitrate) == (160, 120, 1_500_000)
        assert status.framerate == pytest.approx(25.0) and status.hfov == 62
        # the legacy command older QGroundControl versions send
        acks = rig.gcs.ack_count(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION)
        count = len(rig.gcs.received.of("VIDEO_STREAM_INFORMATION"))
        rig.gcs.command_long(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, [1, 0, 0, 0, 0, 0, 0], target=CAM)
        ack = rig.gcs.wait_ack(mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, acks, WAIT_S)
        assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
        assert rig.gcs.received.wait_for(lambda: len(rig.gcs.received.of("VIDEO_STREAM_INFORMATION")) > count, WAIT_S)
    finally:
        rig.close()


def test_without_the_stream_the_camera_neither_announces_nor_answers_it(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(10):
        cv2.imwrite(str(frames / f"{i:04d}.png"), scene((160, 120), (60 + i, 40), 20))
    rig = Rig({"source": {"path": str(frames), "loop": True}})
    try:
        assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", WAIT_S)
        info = camera_information(rig)
        assert not info.flags & mavlink.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        for message_id, kind in ((mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, "VIDEO_STREAM_INFORMATION"),
                                 (mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS, "VIDEO_STREAM_STATUS")):
            assert request(rig, message_id, kind) == (UNSUPPORTED, None)
        assert rig.service.stream is None and rig.service.status()["video"]["stream"] is None
    finally:
        rig.close()
