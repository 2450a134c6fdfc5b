"""Video out of the daemon: the Zenoh JPEG preview (frame id / capture time as in the telemetry,
latest-frame-wins with a stalled consumer, rate thinning, sizes) and its configuration."""
from __future__ import annotations

import json
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.fuzz import zenoh_session
from service.app import Service
from service.config import ConfigError, PreviewConfig, config_from_mapping
from service.sources.base import Frame
from service.sources.zenoh_wire import decode_frame
from service.video.latest_frame_worker import LatestFrameWorker, Pace, fit_size, pace_step
from service.video.zenoh_preview import preview_payload
from sim.ports import free_tcp_port, free_udp_port
from tests.service_peers import Recorder, RunningService, service_config
from tests.test_service_sources import scene

WAIT_S = 20.0  # generous: the machine is shared


def frame(frame_id: int, at_s: float, size: tuple[int, int] = (64, 48)) -> Frame:
    return Frame(np.full((size[1], size[0], 3), frame_id % 256, np.uint8), frame_id, 1000.0 + at_s, at_s)


# --- pure pieces ---------------------------------------------------------------------------------
def test_fit_size_scales_down_keeping_aspect_and_never_enlarges() -> None:
    assert fit_size((640, 480), (320, 240)) == (320, 240)
    assert fit_size((640, 480), (320, 480)) == (320, 240)
    assert fit_size((360, 240), (640, 480)) == (360, 240)
    assert fit_size((1920, 1080), (640, 480)) == (640, 360)
    assert fit_size((641, 481), (641, 481), even=True) == (640, 480)
    assert fit_size((1000, 3), (100, 100), even=True) == (100, 2)


def test_pacing_thins_30_fps_to_15_and_keeps_every_frame_at_the_camera_rate() -> None:
    def taken(fps_in: float, max_fps: float, n: int, jitter_s: float = 0.0) -> int:
        pace, count = Pace(), 0
        rng = np.random.default_rng(1)
        for i in range(n):
            due, pace = pace_step(pace, i / fps_in + rng.uniform(-jitter_s, jitter_s), 1.0 / max_fps)
            count += due
        return count

    assert taken(30, 15, 300) == 150
    assert taken(30, 30, 300, jitter_s=0.004) == 300
    assert taken(30, 10, 300, jitter_s=0.004) == 100
    assert taken(30, 100, 300) == 300


def test_pacing_restarts_after_a_gap_instead_of_bursting() -> None:
    pace = Pace()
    due, pace = pace_step(pace, 0.0, 0.1)
    assert due
    due, pace = pace_step(pace, 5.0, 0.1)  # frames stopped for 5 s
    assert due and pace.next_due_s == pytest.approx(5.1)
    due, pace = pace_step(pace, 5.02, 0.1)
    assert not due


def test_preview_payload_carries_the_frames_own_id_and_capture_time_and_fits_the_size() -> None:
    image = scene((640, 480), (300, 200))
    capture_time = 1764680000.123456789  # a wall-clock float64, exactly what FrameReport.as_json carries
    payload = preview_payload(Frame(image, 12345678901, capture_time, 0.0),
                              PreviewConfig(max_width_px=320, max_height_px=320, jpeg_quality=90))
    decoded = decode_frame(payload)
    assert payload[4:8] == b"JPEG"
    assert decoded.frame_id == 12345678901
    assert decoded.timestamp == capture_time  # bit-exact: the telemetry's json float round-trips too
    assert json.loads(json.dumps({"capture_time": capture_time}))["capture_time"] == decoded.timestamp
    assert decoded.image.shape == (240, 320, 3)
    expected = cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA)
    def coarse(img: np.ndarray) -> np.ndarray:  # JPEG keeps the picture, not the fine texture
        return cv2.resize(img, (40, 30), interpolation=cv2.INTER_AREA).astype(int)

    assert np.abs(coarse(decoded.image) - coarse(expected)).mean() < 4
    assert np.abs(coarse(decoded.image) - coarse(np.roll(expected, 40, axis=1))).mean() > 10  # the test can fail


# --- latest-frame-wins ---------------------------------------------------------------------------
def test_a_stalled_consumer_never_blocks_the_offering_thread_and_drops_are_counted() -> None:
    entered, release = threading.Event(), threading.Event()
    seen: list[int] = []

    def stalled_sink(f: Frame) -> None:
        seen.append(f.frame_id)
        entered.set()
        assert release.wait(WAIT_S), "the test never released the sink"

    worker = LatestFrameWorker("test", stalled_sink, max_fps=1000.0)
    worker.start()
    try:
        worker.offer(frame(0, 0.0))
        assert entered.wait(WAIT_S), "the worker never took the first frame"
        offered = threading.Event()

        def offer_many() -> None:  # plays the tracking loop while the consumer is stuck
            for i in range(1, 101):
                worker.offer(frame(i, i * 0.01))
            offered.set()

        loop = threading.Thread(target=offer_many, daemon=True)
        loop.start()
        assert offered.wait(WAIT_S), "offer() blocked behind a stalled consumer"
        assert not release.is_set() and seen == [0]  # the consumer was stuck the whole time
        assert worker.dropped == 99  # frames 1..99 replaced before the consumer could take them
        release.set()
        assert worker.wait_until(lambda: worker.sent == 2, WAIT_S)
        assert seen == [0, 100]  # after the stall, the newest frame, nothing queued
        counters = worker.counters()
        assert counters.pop("cpu_ms") >= 0
        assert counters == {"offered": 101, "rate_skipped": 0, "dropped": 99, "sent": 2, "errors": 0}
    finally:
        release.set()
        worker.stop()


def test_a_failing_consumer_is_counted_and_the_worker_carries_on() -> None:
    done = threading.Event()
    calls: list[int] = []

    def sink(f: Frame) -> None:
        calls.append(f.frame_id)
        if f.frame_id == 0:
            raise OSError("link down")
        done.set()

    worker = LatestFrameWorker("test", sink, max_fps=1000.0)
    worker.start()
    try:
        worker.offer(frame(0, 0.0))
        assert worker.wait_until(lambda: worker.errors == 1, WAIT_S)
        worker.offer(frame(1, 0.1))
        assert done.wait(WAIT_S)
        assert worker.wait_until(lambda: worker.sent == 1, WAIT_S) and calls == [0, 1]
    finally:
        worker.stop()


# --- configuration -------------------------------------------------------------------------------
@pytest.mark.parametrize("video, message", [
    ({"preview": {"jpeg_quality": 0}}, "video.preview.jpeg_quality: must be in [1, 100], got 0"),
    ({"preview": {"max_fps": 0}}, "video.preview.max_fps: must be > 0"),
    ({"preview": {"max_width_px": 320.5}}, "video.preview.max_width_px: must be an integer"),
    ({"preview": {"enabled": "yes"}}, "video.preview.enabled: must be true or false"),
    ({"preview": {"size": 3}}, "video.preview.size: unknown key"),
    ({"stream": {"enabled": True}}, "video.stream.host: must name the ground station's address"),
    ({"stream": {"enabled": True, "host": "udp://10.0.0.2:5600"}}, "video.stream.host: must be an IPv4 address"),
    ({"stream": {"port": 70000}}, "video.stream.port: must be in [1, 65535]"),
    ({"stream": {"bitrate_kbps": 10}}, "video.stream.bitrate_kbps: must be in [100, 50000]"),
    ({"stream": {"fps": 0}}, "video.stream.fps: must be in [1.0, 120.0]"),
    ({"rtsp": {}}, "video.rtsp: unknown key"),
])
def test_video_config_errors_name_the_key(video: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        config_from_mapping({"video": video})
    assert message in str(err.value)


def test_the_documented_config_yaml_matches_the_defaults() -> None:
    import yaml

    from service.config import VideoConfig, as_plain

    documented = yaml.safe_load((Path(__file__).resolve().parents[1] / "config.yaml").read_text())["video"]
    assert config_from_mapping({"video": documented}).video == VideoConfig()
    assert as_plain(config_from_mapping({})).keys() >= {"video"}


# --- the daemon ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def vga_frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("vga_frames")
    for i in range(30):
        cv2.imwrite(str(folder / f"{i:04d}.jpg"), scene((640, 480), (200 + 5 * i, 240), 60))
    return folder


def test_the_daemon_publishes_previews_stamped_like_the_telemetry_and_survives_a_stalled_viewer(
        vga_frames: Path) -> None:
    zenoh_port = free_tcp_port()
    config = service_config(free_udp_port(), {
        "source": {"path": str(vga_frames), "loop": True, "fps": 30.0},
        "zenoh": {"enabled": True, "listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "videotest"},
        "video": {"preview": {"max_width_px": 320, "max_height_px": 320, "max_fps": 100.0, "jpeg_quality": 60}},
        "logging": {"level": "INFO"},
    })
    running = RunningService(Service(config)).start()
    viewer, stalled_viewer = zenoh_session(zenoh_port), zenoh_session(zenoh_port)
    reports, previews = Recorder(), Recorder()
    unblock, stalled_entered = threading.Event(), threading.Event()

    def stalled(sample: object) -> None:  # a viewer on a dead-slow link: takes one sample, then hangs
        stalled_entered.set()
        unblock.wait(WAIT_S)

    try:
        viewer.declare_subscriber("videotest/track", lambda s: reports.add(json.loads(s.payload.to_string())))
        viewer.declare_subscriber("videotest/camera/preview", lambda s: previews.add(decode_frame(s.payload.to_bytes())))
        stalled_viewer.declare_subscriber("videotest/camera/preview", stalled)
        assert previews.wait_for(lambda: len(previews.items) >= 40, WAIT_S), "fewer than 40 previews arrived"
        assert stalled_entered.wait(WAIT_S), "the stalled viewer never got a preview"
        # the stalled viewer holds its sample; the loop keeps going: 60 more tracked frames meanwhile
        with reports._cond:
            reached = len(reports.items)
        assert reports.wait_for(lambda: len(reports.items) >= reached + 60, WAIT_S), "the loop stalled"
        assert not unblock.is_set()
        stamps = {}
        with reports._cond:
            for r in reports.items:
                stamps[r.msg["frame_id"]] = r.msg["capture_time"]
                assert r.msg["image_size"] == [640, 480]
        with previews._cond:
            samples = [r.msg for r in previews.items]
        matched = [p for p in samples if p.frame_id in stamps]
        assert len(matched) >= 30, "previews do not belong to tracked frames"
        for p in matched:
            assert p.timestamp == stamps[p.frame_id]  # bit-exact, as the ground station matches them
            assert p.image.shape == (240, 320, 3)
        ids = [p.frame_id for p in samples]
        assert ids == sorted(ids) and len(set(ids)) == len(ids)
        status = json.loads(list(viewer.get("videotest/status", timeout=5.0))[0].ok.payload.to_string())
        preview = status["video"]["preview"]
        assert preview["key"] == "videotest/camera/preview"
        assert preview["sent"] >= 40 and preview["errors"] == 0
        in_flight = preview["offered"] - preview["sent"] - preview["dropped"] - preview["rate_skipped"]
        assert 0 <= in_flight <= 2  # every offered frame is sent, dropped or thinned out (but the one in hand)
        assert status["counters"]["preview_sent"] >= 40 and "preview_dropped" in status["counters"]
        assert status["config"]["video"]["preview"]["max_width_px"] == 320
    finally:
        unblock.set()
        viewer.close()
        stalled_viewer.close()
        running.stop()
