"""Headline test: a real shared sequence played as a video file; a ground-station peer selects the
target with TRACK_RECTANGLE, gets ACCEPTED and CAMERA_TRACKING_IMAGE_STATUS at the requested interval
with the box following the ground truth; the autopilot peer receives gimbal rates whose signs match
the target's offset from the image centre; STOP_TRACKING ends both."""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from service.app import Service
from sim.ports import free_tcp_port, free_udp_ports
from tests.helpers import real_sequence
from tests.service_peers import AutopilotPeer, GroundStation, Recorder, RunningService, service_config

SEQUENCE = "OTB_Crossing"  # 360x240, 120 frames, a pedestrian crossing from right of centre to left
FPS = 30.0
TRACK_RECT, STOP, INTERVAL = 2005, 2010, 511
STATUS_INTERVAL_US = 100_000


def write_video(folder: Path, path: Path) -> tuple[int, int, int]:
    """The sequence's frames as an MJPG .avi at FPS; returns (frames, width, height)."""
    images = sorted((folder / "img").glob("*.jpg"))
    first = cv2.imread(str(images[0]))
    height, width = first.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (width, height))
    for image_path in images:
        writer.write(cv2.imread(str(image_path)))
    writer.release()
    return len(images), width, height


@pytest.mark.slow
def test_track_rectangle_on_a_real_sequence_end_to_end(data_root: Path, tmp_path: Path) -> None:
    import zenoh

    gt = real_sequence(data_root, SEQUENCE).groundtruth
    video = tmp_path / "crossing.avi"
    n_frames, width, height = write_video(data_root / SEQUENCE, video)
    assert len(gt) == n_frames

    (service_port, gcs_port), zenoh_port = free_udp_ports(2), free_tcp_port()
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=1).start()
    gcs = GroundStation(gcs_port).start()
    config = service_config(service_port, {
        "source": {"path": str(video), "realtime": True, "loop": True},
        "zenoh": {"enabled": True, "listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "e2e"},
        "camera": {"hfov_deg": 60.0},
        "logging": {"level": "INFO"},
    })
    running = RunningService(Service(config)).start()
    zc = zenoh.Config()
    zc.insert_json5("mode", '"peer"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
    session = zenoh.open(zc)
    reports = Recorder()
    subscriber = session.declare_subscriber("e2e/track", lambda s: reports.add(json.loads(s.payload.to_string())))
    try:
        def frames() -> list[dict]:
            with reports._cond:
                return [r.msg for r in reports.items]

        # wait for the start of a pass through the file, as an operator waits for the target to be in view
        assert reports.wait_for(lambda: any(2 <= f["frame_id"] % n_frames < 8 for f in frames()), 20.0)
        current = max(f["frame_id"] for f in frames() if 2 <= f["frame_id"] % n_frames < 8)
        pass_start = current - current % n_frames
        x, y, w, h = gt[(current + 1) % n_frames]
        gcs.command_long(INTERVAL, [275, STATUS_INTERVAL_US, 0, 0, 0, 0, 0])
        assert gcs.wait_ack(INTERVAL, 0).result == 0
        gcs.command_long(TRACK_RECT, [x / width, y / height, (x + w) / width, (y + h) / height, 0, 0, 0])
        ack = gcs.wait_ack(TRACK_RECT, 0)
        assert ack is not None and ack.result == 0  # ACCEPTED

        # let it track through most of the pass, then stop
        assert reports.wait_for(lambda: any(f["frame_id"] >= pass_start + n_frames - 15 for f in frames()), 30.0)
        gcs.command_long(STOP, [0, 0, 0, 0, 0, 0, 0])
        assert gcs.wait_ack(STOP, 0).result == 0
        stop_at = [r for r in gcs.received.of("COMMAND_ACK") if r.msg.command == STOP][0].at
        assert gcs.received.wait_for(lambda: any(r.msg.tracking_status == 0 and r.at > stop_at
                                                 for r in gcs.received.of("CAMERA_TRACKING_IMAGE_STATUS")), 5.0)
        idle_after = [f for f in frames() if f["state"] == "idle" and f["frame_id"] > current + 10]
        assert reports.wait_for(lambda: len([f for f in frames() if f["state"] == "idle" and f["frame_id"] > current + 10])
                                >= len(idle_after) + 10, 5.0)  # ten more frames processed after the stop
    finally:
        subscriber.undeclare()
        session.close()
        running.stop()
        gcs.close()
        autopilot.close()

    # --- the box follows the ground truth ------------------------------------------------------------
    tracked = [f for f in frames() if f["state"] != "idle"]
    assert len(tracked) >= 60
    errors = []
    for f in tracked:
        gx, gy, gw, gh = gt[f["frame_id"] % n_frames]
        bx, by, bw, bh = f["box_px"]
        errors.append(math.hypot(bx + bw / 2 - gx - gw / 2, by + bh / 2 - gy - gh / 2))
    assert np.mean(np.array(errors) < 20.0) >= 0.9, f"centre errors {np.round(errors, 1)}"

    # --- 275 at the requested interval, ACTIVE, with the tracked box --------------------------------
    statuses = [r for r in gcs.received.of("CAMERA_TRACKING_IMAGE_STATUS") if r.at < stop_at]
    active = [r for r in statuses if r.msg.tracking_status == 1]
    assert len(active) >= 15 and all(r.msg.tracking_mode == 2 for r in active)  # RECTANGLE
    gaps = sorted(b.at - a.at for a, b in zip(active, active[1:]))
    median_gap = gaps[len(gaps) // 2]
    assert 0.5 * STATUS_INTERVAL_US / 1e6 < median_gap < 1.5 * STATUS_INTERVAL_US / 1e6
    by_box = {tuple(np.float32(f["box_norm"])): f for f in tracked}
    matched = 0
    for r in active:
        m = r.msg
        key = tuple(np.float32([m.rec_top_x, m.rec_top_y, m.rec_bottom_x - m.rec_top_x, m.rec_bottom_y - m.rec_top_y]))
        near = [f for k, f in by_box.items() if np.allclose(k, key, atol=1e-5)]
        if near:
            matched += 1
            gx, gy, gw, gh = gt[near[0]["frame_id"] % n_frames]
            assert abs(m.point_x * width - (gx + gw / 2)) < 25 and abs(m.point_y * height - (gy + gh / 2)) < 25
    assert matched >= 0.8 * len(active)

    # --- gimbal rates: one 287 per tracked frame, signs towards the target ---------------------------
    all_rates = autopilot.from_service.of("GIMBAL_MANAGER_SET_PITCHYAW")
    rates = all_rates[:-1]  # the last one is the zero command sent on stop
    assert len(rates) == len(tracked), (len(rates), len(tracked))
    agree_yaw = agree_pitch = checked_yaw = checked_pitch = 0
    for f, r in zip(tracked, rates):
        gx, gy, gw, gh = gt[f["frame_id"] % n_frames]
        dx, dy = gx + gw / 2 - width / 2, gy + gh / 2 - height / 2
        if abs(dx) > 0.1 * width:
            checked_yaw += 1
            agree_yaw += (r.msg.yaw_rate > 0) == (dx > 0)
        if abs(dy) > 0.1 * height:
            checked_pitch += 1
            agree_pitch += (r.msg.pitch_rate > 0) == (dy < 0)  # image y down, pitch up positive
    assert checked_yaw >= 20 and checked_pitch >= 20
    print(f"tracked={len(tracked)} rates={len(rates)} yaw {agree_yaw}/{checked_yaw} pitch {agree_pitch}/{checked_pitch} "
          f"median centre error {np.median(errors):.1f} px, 275 median gap {median_gap:.3f} s, matched {matched}/{len(active)}")
    assert agree_yaw >= 0.9 * checked_yaw and agree_pitch >= 0.9 * checked_pitch

    # --- STOP_TRACKING ends both ------------------------------------------------------------------------
    after = [r.msg for r in all_rates if r.at >= stop_at]  # at most one tracked frame's command was in flight
    assert 1 <= len(after) <= 2 and after[-1].yaw_rate == 0 and after[-1].pitch_rate == 0
    assert all_rates[-1].msg is after[-1]  # nothing after the zero command, though ten more frames were processed
    last_status = [r.msg for r in gcs.received.of("CAMERA_TRACKING_IMAGE_STATUS")][-1]
    assert last_status.tracking_status == 0 and last_status.tracking_mode == 0
