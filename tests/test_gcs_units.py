"""The ground side's pure pieces: the preview decoder (cross-checked against the service's encoder: gcs/
has its own, written from the documented format), STATUSTEXT reassembly (against the daemon's chunking),
the page-facing helpers, Zenoh settings."""
from __future__ import annotations

import os
import struct

os.environ.setdefault("MAVLINK20", "1")

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from gcs.confidence import LOW_CONFIDENCE, ConfidenceGauge
from gcs.drones import ZenohSettings, autopilot_summary
from gcs.mavlink_station import StatusTextAssembler, tracking_status_name
from gcs.preview import decode_preview, drone_prefix
from gcs.web.__main__ import is_loopback
from gcs.web.server import finite, same_origin
from service.mavlink.messages import status_texts
from service.sources.zenoh_wire import encode_frame


def test_preview_decoder_reads_what_the_service_encodes() -> None:
    image = np.random.default_rng(1).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    payload = encode_frame(image, 123456789012, 1048576.0333333497, b"JPEG", 80)
    frame = decode_preview(payload)
    assert (frame.width, frame.height, frame.frame_id) == (160, 120, 123456789012)
    assert frame.capture_time == 1048576.0333333497  # bit for bit: it pairs the frame with its track sample
    decoded = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (120, 160, 3)


def test_preview_decoder_refuses_what_is_not_a_jpeg_preview() -> None:
    image = np.zeros((8, 8, 3), np.uint8)
    good = encode_frame(image, 1, 0.0, b"JPEG")
    with pytest.raises(ValueError, match="too short"):
        decode_preview(good[:20])
    with pytest.raises(ValueError, match="magic"):
        decode_preview(b"XXXX" + good[4:])
    with pytest.raises(ValueError, match="is not b'JPEG'"):
        decode_preview(encode_frame(image, 1, 0.0, b"BGR3"))
    with pytest.raises(ValueError, match="empty"):
        decode_preview(good[:8] + struct.pack("<II", 0, 8) + good[16:])
    with pytest.raises(ValueError, match="start-of-image"):
        decode_preview(good[:32] + b"\x00\x00" + good[34:])
    with pytest.raises(ValueError, match="truncated"):
        decode_preview(good[:-10])


def test_drone_prefix() -> None:
    assert drone_prefix("jsar/track", "track") == "jsar"
    assert drone_prefix("fleet/d2/camera/preview", "camera/preview") == "fleet/d2"
    assert drone_prefix("track", "track") is None
    assert drone_prefix("jsar/status", "track") is None
    assert drone_prefix("jsar/xtrack", "track") is None


@pytest.mark.parametrize("text", ["TRACK_POINT DENIED: short",
                                  "TRACK_RECTANGLE DENIED: rectangle (0.5, 0.2)-(0.3, 0.4) is inverted or has zero size",
                                  "x" * 100, "y" * 50])
def test_statustext_chunks_from_the_daemon_reassemble(text: str) -> None:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=100)
    parser = mavlink2.MAVLink(None)
    assembler = StatusTextAssembler()
    done = []
    for message in status_texts(mav, 4, text, text_id=7):
        received = parser.parse_char(message.pack(mav))  # through the wire format, as a receiver sees it
        done.append(assembler.add(received.id, received.chunk_seq, received.text, received.severity, 1.0))
    assert done[-1] == text and all(d is None for d in done[:-1])
    assert assembler.since(0.5) == [text] and assembler.since(1.5) == []


def test_statustext_chunks_of_two_texts_interleaved() -> None:
    assembler = StatusTextAssembler()
    assert assembler.add(5, 0, "a" * 50, 4, 0.0) is None
    assert assembler.add(6, 0, "plain", 4, 0.0) == "plain"  # another id completes on its own
    assert assembler.add(5, 1, "end", 4, 0.0) == "a" * 50 + "end"
    assert assembler.add(0, 0, "single", 6, 0.0) == "single"
    assert assembler.add(9, 1, "tail", 4, 0.0) == "[...]tail"  # a lost first chunk is marked, not hidden


def test_tracking_status_names() -> None:
    assert tracking_status_name(0) == "IDLE"
    assert tracking_status_name(1) == "ACTIVE"
    assert tracking_status_name(8) == "COASTING"
    assert tracking_status_name(1 | 8) == "ACTIVE|COASTING"


def test_finite_json() -> None:
    assert finite({"a": float("nan"), "b": [1.0, float("inf"), {"c": 2}], "d": "x"}) == \
        {"a": None, "b": [1.0, None, {"c": 2}], "d": "x"}


def test_websocket_origin_check() -> None:
    assert same_origin(None, "127.0.0.1:8080")  # not a browser page
    assert same_origin("http://127.0.0.1:8080", "127.0.0.1:8080")
    assert same_origin("https://gcs.example:443", "GCS.example:443")
    assert not same_origin("http://evil.example", "127.0.0.1:8080")
    assert not same_origin("http://127.0.0.1:9999", "127.0.0.1:8080")
    assert not same_origin("http://127.0.0.1:8080", None)


def test_loopback_hosts() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost") and is_loopback("127.1.2.3")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5") and not is_loopback("gcs.local")


def test_zenoh_settings_need_a_way_to_reach_daemons() -> None:
    with pytest.raises(ValueError, match="endpoint"):
        ZenohSettings()
    with pytest.raises(ValueError, match="client mode"):
        ZenohSettings(listen=("tcp/127.0.0.1:7447",), mode="client")
    with pytest.raises(ValueError, match="peer or client"):
        ZenohSettings(connect=("tcp/127.0.0.1:7447",), mode="router")
    ZenohSettings(connect=("tcp/127.0.0.1:7447",), mode="client").to_zenoh()


def test_the_ground_side_imports_nothing_of_the_service_the_sim_or_the_tracker() -> None:
    """gcs/ runs on a ground station: only the public wire formats, never service / sim / jsar / bench code."""
    from tests.test_import_graph import import_graph, within
    graph = import_graph()
    assert any(within(module, ("gcs",)) for module in graph)
    wrong = {(module, name) for module, names in graph.items() if within(module, ("gcs",))
             for name in names if within(name, ("service", "sim", "jsar", "bench"))}
    assert not wrong


def test_confidence_is_the_score_against_the_best_of_the_lock() -> None:
    gauge = ConfidenceGauge()
    assert gauge.update({"state": "idle", "score": None}) is None
    # a JSAR lock: the raw peak rises as the filter learns, then the target fades (a drifting or false lock)
    shown = [gauge.update({"state": "tracking", "score": score}) for score in (0.026, 0.04, 0.06, 0.05, 0.0419)]
    assert [c["percent"] for c in shown] == [100, 100, 100, 83, 69]
    assert [c["low"] for c in shown] == [False, False, False, False, True]  # 69 % < 70 %: low, still "tracking"
    assert shown[-1]["reference"] == 0.06 and shown[-1]["low_below"] == LOW_CONFIDENCE == 0.7
    assert gauge.update({"state": "tracking", "score": 0.042})["low"] is False  # exactly 70 %: not low
    lost = gauge.update({"state": "lost", "score": 0.012})  # while lost: against the same lock's best
    assert (lost["percent"], lost["reference"]) == (20, 0.06)
    assert gauge.update({"state": "lost", "score": 0.09})["reference"] == 0.06  # a lost frame never raises it
    # re-detected: a new lock, its own reference
    assert gauge.update({"state": "recovered", "score": 0.02}) == {"percent": 100, "low": False,
                                                                   "low_below": 0.7, "reference": 0.02}
    # a new selection while tracking (this station's command accepted): the reference starts again
    gauge.update({"state": "tracking", "score": 0.03})
    gauge.new_lock()
    assert gauge.update({"state": "tracking", "score": 0.01})["percent"] == 100
    # OpenCV's trackers score 1 / 0; a sample without a usable score shows none
    kcf = ConfidenceGauge()
    assert kcf.update({"state": "tracking", "score": 1.0})["percent"] == 100
    assert kcf.update({"state": "lost", "score": 0.0})["percent"] == 0
    for score in (None, float("nan"), True, "0.5"):
        assert ConfidenceGauge().update({"state": "tracking", "score": score}) is None
    assert ConfidenceGauge().update({"state": "tracking", "score": 0.0}) is None  # no positive best yet


def test_autopilot_and_gimbal_from_the_daemons_status() -> None:
    def status(state: str, heard: int | None, configured: int = 0, backend: str = "ardupilot",
               gimbal_heard: bool | None = True) -> dict:
        autopilot = {"system_id": heard, "alive": state == "connected", "state": state, "custom_mode": None}
        if gimbal_heard is not None:
            autopilot["gimbal_attitude_heard"] = gimbal_heard
        return {"autopilot": autopilot, "config": {"mavlink": {"system_id": configured}, "gimbal": {"backend": backend}}}

    assert autopilot_summary(status("connected", 1)) == {
        "state": "connected", "system_id": 1, "configured_system_id": 0, "gimbal_backend": "ardupilot",
        "gimbal_commands": "sent", "gimbal_attitude": True}
    # a gimbal that never reported its attitude; a daemon that does not say (older): unknown, not "absent"
    assert autopilot_summary(status("connected", 1, gimbal_heard=False))["gimbal_attitude"] is False
    assert autopilot_summary(status("connected", 1, gimbal_heard=None))["gimbal_attitude"] is None
    # never heard, nothing configured: the daemon holds its gimbal commands (nobody to send them to)
    none = autopilot_summary(status("waiting_for_heartbeat", None))
    assert (none["state"], none["system_id"], none["gimbal_commands"]) == ("waiting_for_heartbeat", None, "held")
    # a configured system id: sent, unanswered; heard once then lost: held until it returns; no gimbal configured
    assert autopilot_summary(status("waiting_for_heartbeat", None, configured=7))["gimbal_commands"] == "sent"
    assert autopilot_summary(status("heartbeat_lost", 1))["gimbal_commands"] == "held"
    assert autopilot_summary(status("connected", 1, backend="none"))["gimbal_commands"] == "none"
    assert autopilot_summary({"status": "ok"}) is None  # an answer without it: unknown, not "none"
