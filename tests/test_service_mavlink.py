"""The camera component on a loopback link with independent pymavlink peers (autopilot + ground station)."""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Iterator

import cv2
import pytest

from service.app import Service
from sim.ports import free_udp_ports
from tests.helpers import write_square_frames
from tests.service_peers import AutopilotPeer, GroundStation, RunningService, service_config
from tests.test_service_sources import scene

AP_SYSID = 42
CAM = (AP_SYSID, 100)
TRACK_RECT, TRACK_POINT, STOP, INTERVAL, REQUEST = 2005, 2004, 2010, 511, 512
ACCEPTED, DENIED, FAILED = 0, 2, 4
NAN = float("nan")


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_square_frames(tmp_path_factory.mktemp("frames"), 30, (110, 40))


class Rig:
    """Autopilot peer + ground station + in-process service."""

    def __init__(self, overrides: dict, autopilot_kwargs: dict | None = None, gcs_key: bytes | None = None) -> None:
        service_port, gcs_port = free_udp_ports(2)
        self.gcs_port = gcs_port
        self.autopilot = AutopilotPeer(service_port, gcs_port, system_id=AP_SYSID, **(autopilot_kwargs or {})).start()
        self.gcs = GroundStation(gcs_port, key=gcs_key).start()
        self.config = service_config(service_port, overrides)
        self.running = RunningService(Service(self.config)).start()
        self.service: Service = self.running.service  # type: ignore[assignment]
        # like a real ground station: command the camera only after its heartbeat came through the autopilot
        # (until the service has sent something, the autopilot does not know where to forward to)
        assert self.wait_service_heartbeats(1, 10.0), "no heartbeat from the camera component"
        # commands to system 42 are not for the camera until it has learned that it belongs to system 42
        assert self.autopilot.from_service.wait_for(lambda: self.service.link.system_id == AP_SYSID, 10.0)

    def close(self) -> None:
        self.running.stop()
        self.gcs.close()
        self.autopilot.close()

    def wait_service_heartbeats(self, count: int, timeout_s: float = 5.0) -> bool:
        def beats() -> int:
            return len([r for r in self.gcs.received.of("HEARTBEAT") if r.msg.get_srcComponent() == 100])
        return self.gcs.received.wait_for(lambda: beats() >= count, timeout_s)

    def wait_tracking(self, timeout_s: float = 5.0) -> bool:
        return self.service.worker.health.wait_for(lambda h: self.service.loop.state == "tracking", timeout_s)


@pytest.fixture
def rig(frames_dir: Path) -> Iterator[Rig]:
    rig = Rig({"source": {"path": str(frames_dir), "loop": True}})
    yield rig
    rig.close()


def test_identity_heartbeat_and_camera_information(rig: Rig) -> None:
    assert rig.wait_service_heartbeats(1)
    beat = [r.msg for r in rig.gcs.received.of("HEARTBEAT") if r.msg.get_srcComponent() == 100][-1]
    assert (beat.type, beat.autopilot) == (30, 8)  # MAV_TYPE_CAMERA, MAV_AUTOPILOT_INVALID
    assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
    assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, 5.0)  # learned
    rig.gcs.command_long(REQUEST, [259, 0, 0, 0, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(REQUEST, 0).result == ACCEPTED
    assert rig.gcs.received.wait_for(lambda: any(r.msg.get_srcSystem() == AP_SYSID
                                                 for r in rig.gcs.received.of("CAMERA_INFORMATION")), 5.0)
    info = [r.msg for r in rig.gcs.received.of("CAMERA_INFORMATION") if r.msg.get_srcSystem() == AP_SYSID][-1]
    assert info.get_srcSystem() == AP_SYSID and info.get_srcComponent() == 100
    assert (info.resolution_h, info.resolution_v) == (160, 120)
    assert info.flags & 512 and info.flags & 1024  # tracking point and rectangle


def test_bad_commands_are_denied_and_change_nothing(rig: Rig) -> None:
    assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
    assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, 5.0)
    # idle: a bad selection leaves it idle
    rig.gcs.command_long(TRACK_RECT, [0.5, 0.2, 0.3, 0.4, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(TRACK_RECT, 0).result == DENIED
    assert rig.service.loop.state == "idle" and rig.service.selections.take(0.0) is None
    rig.gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(TRACK_RECT, 1).result == ACCEPTED
    assert rig.wait_tracking()
    tracker, kind = rig.service.loop.tracker, rig.service.loop.selection_kind
    bad_long = [
        (TRACK_POINT, [NAN, 0.5, 0.1, 0, 0, 0, 0]),
        (TRACK_POINT, [1.5, 0.5, 0.1, 0, 0, 0, 0]),
        (TRACK_POINT, [0.5, 0.5, 0.1, 9, 0, 0, 0]),  # unknown camera id
        (TRACK_RECT, [0.5, 0.5, 0.2, 0.6, 0, 0, 0]),  # inverted
        (TRACK_RECT, [0.5, 0.5, 0.5, 0.5, 0, 0, 0]),  # zero size
        (TRACK_RECT, [0.1, 0.1, 0.2, 0.2, 103, 0, 0]),  # unknown camera id
        (STOP, [77, 0, 0, 0, 0, 0, 0]),  # stop for another camera
    ]
    acks = {TRACK_POINT: 0, TRACK_RECT: 2, STOP: 0}
    for command, params in bad_long:
        rig.gcs.command_long(command, params, target=CAM)
        assert rig.gcs.wait_ack(command, acks[command]).result == DENIED, (command, params)
        acks[command] += 1
    rig.gcs.command_int(TRACK_RECT, 0.1, NAN, 0.3, 0.4, 0, 0, 0, target=CAM)  # COMMAND_INT too
    assert rig.gcs.wait_ack(TRACK_RECT, acks[TRACK_RECT]).result == DENIED
    assert rig.service.loop.tracker is tracker and rig.service.loop.selection_kind == kind
    assert rig.service.loop.state in ("tracking", "recovered", "lost")
    assert rig.service.selections.take(0.0) is None  # nothing was queued for the loop
    # STOP via COMMAND_INT ends tracking
    rig.gcs.command_int(STOP, 0, 0, 0, 0, 0, 0, 0, target=CAM)
    assert rig.gcs.wait_ack(STOP, acks[STOP]).result == ACCEPTED
    assert rig.service.worker.health.wait_for(lambda h: rig.service.loop.state == "idle", 5.0)


def test_status_stream_follows_the_requested_interval_and_turns_off(rig: Rig) -> None:
    assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
    assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, 5.0)
    rig.gcs.command_long(TRACK_POINT, [0.6, 0.33, 0.0, 0, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(TRACK_POINT, 0).result == ACCEPTED
    rig.gcs.command_long(INTERVAL, [275, 50000, 0, 0, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(INTERVAL, 0).result == ACCEPTED

    def statuses() -> list:
        return rig.gcs.received.of("CAMERA_TRACKING_IMAGE_STATUS")
    assert rig.gcs.received.wait_for(lambda: len([s for s in statuses() if s.msg.tracking_status == 1]) >= 8, 5.0)
    active = [s for s in statuses() if s.msg.tracking_status == 1]
    assert active[-1].msg.tracking_mode == 1  # POINT
    gaps = sorted(b.at - a.at for a, b in zip(active, active[1:]))
    assert 0.025 < gaps[len(gaps) // 2] < 0.1  # median near the requested 50 ms, not the frame rate
    x0, y0, x1, y1 = (active[-1].msg.rec_top_x, active[-1].msg.rec_top_y, active[-1].msg.rec_bottom_x,
                      active[-1].msg.rec_bottom_y)
    assert 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1
    rig.gcs.command_long(INTERVAL, [275, -1, 0, 0, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(INTERVAL, 1).result == ACCEPTED
    off_at = rig.gcs.received.of("COMMAND_ACK")[-1].at
    beats = len(rig.gcs.received.of("HEARTBEAT"))
    # two more heartbeats from everyone (>= 1 s of silence from the status stream)
    assert rig.gcs.received.wait_for(lambda: len([r for r in rig.gcs.received.of("HEARTBEAT")
                                                  if r.msg.get_srcComponent() == 100]) >= 2 and
                                     len(rig.gcs.received.of("HEARTBEAT")) > beats + 10, 5.0)
    assert len([s for s in statuses() if s.at > off_at]) <= 1  # at most one already in flight


def test_track_command_fails_without_camera_frames(tmp_path: Path) -> None:
    junk = tmp_path / "junk.avi"  # there but unreadable: a source fault, retried (a missing file is a config error)
    junk.write_bytes(b"not a video")
    rig = Rig({"source": {"path": str(junk)}})
    try:
        assert rig.service.worker.health.wait_for(lambda h: h.failures >= 1, 5.0)
        assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, 5.0)
        assert rig.wait_service_heartbeats(1)
        beat = [r.msg for r in rig.gcs.received.of("HEARTBEAT") if r.msg.get_srcComponent() == 100][-1]
        assert beat.system_status == 5  # MAV_STATE_CRITICAL while the source fails
        rig.gcs.command_long(TRACK_RECT, [0.1, 0.1, 0.3, 0.3, 0, 0, 0], target=CAM)
        ack = rig.gcs.wait_ack(TRACK_RECT, 0)
        assert ack.result == FAILED
        rig.gcs.command_long(REQUEST, [259, 0, 0, 0, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(REQUEST, 0).result == 1  # TEMPORARILY_REJECTED: no real frame size yet
        assert rig.gcs.received.of("CAMERA_INFORMATION") == []  # never announced with a made-up size
        assert rig.service.loop.state == "idle"
        assert rig.service.status()["source"]["state"] == "error"
    finally:
        rig.close()


def test_signing_accepts_signed_peers_and_rejects_unsigned(tmp_path: Path, frames_dir: Path) -> None:
    key = bytes(range(32))
    key_file = tmp_path / "mavlink.key"
    key_file.write_text(key.hex())
    rig = Rig({"source": {"path": str(frames_dir), "loop": True},
               "mavlink": {"system_id": AP_SYSID, "signing": {"key_file": str(key_file)}}})
    unsigned = rig.gcs
    signed = GroundStation(rig.gcs_port, key=key).start()
    try:
        assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
        unsigned.command_long(INTERVAL, [275, 100000, 0, 0, 0, 0, 0], target=CAM)
        signed.command_long(INTERVAL, [275, 200000, 0, 0, 0, 0, 0], target=CAM)
        ack = signed.wait_ack(INTERVAL, 0)
        assert ack is not None and ack.result == ACCEPTED
        # the autopilot forwards every ACK to both ground stations: only one was ever sent
        assert signed.received.wait_for(lambda: unsigned.ack_count(INTERVAL) >= 1, 5.0)
        assert signed.ack_count(INTERVAL) == 1 and unsigned.ack_count(INTERVAL) == 1
        assert rig.service.camera.intervals()[275] == pytest.approx(0.2)  # the signed request won
        assert rig.service.camera.counters["commands"] == 1
    finally:
        signed.close()
        rig.close()


def test_autopilot_heartbeat_timeout_and_guidance_only_in_guided(frames_dir: Path) -> None:
    rig = Rig({"source": {"path": str(frames_dir), "loop": True}, "guidance": {"mode": "velocity", "rate_hz": 20.0}},
              autopilot_kwargs={"custom_mode": 5})  # ArduCopter LOITER
    ap = rig.autopilot
    try:
        assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
        assert rig.gcs.received.wait_for(lambda: rig.service.camera.autopilot_alive(), 5.0)
        rig.gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(TRACK_RECT, 0).result == ACCEPTED

        def count(kind: str) -> int:
            return len(ap.from_service.of(kind))
        assert ap.from_service.wait_for(lambda: count("GIMBAL_MANAGER_SET_PITCHYAW") >= 10, 5.0)
        assert count("SET_POSITION_TARGET_LOCAL_NED") == 0  # LOITER: no guidance
        ap.custom_mode = 4  # the operator switches to GUIDED
        assert ap.from_service.wait_for(lambda: count("SET_POSITION_TARGET_LOCAL_NED") >= 3, 5.0)
        setpoint = ap.from_service.of("SET_POSITION_TARGET_LOCAL_NED")[-1].msg
        assert setpoint.type_mask == 0x05C7 and setpoint.coordinate_frame == 8 and setpoint.target_system == AP_SYSID
        ap.heartbeats_on = False  # link to the autopilot goes quiet
        assert rig.gcs.received.wait_for(lambda: not rig.service.camera.autopilot_alive(), 5.0)
        before = count("SET_POSITION_TARGET_LOCAL_NED")
        gimbal = count("GIMBAL_MANAGER_SET_PITCHYAW")
        # silent: gimbal and guidance commands are held (issue 42), counted while frames keep being tracked
        held = rig.service.outputs.counters["held"]
        assert ap.from_service.wait_for(lambda: rig.service.outputs.counters["held"] >= held + 10, 5.0)
        assert count("GIMBAL_MANAGER_SET_PITCHYAW") <= gimbal + 1  # one may have been in flight
        assert count("SET_POSITION_TARGET_LOCAL_NED") <= before + 1
        ap.heartbeats_on = True  # back: both resume by themselves
        assert ap.from_service.wait_for(lambda: count("GIMBAL_MANAGER_SET_PITCHYAW") >= gimbal + 10
                                        and count("SET_POSITION_TARGET_LOCAL_NED") >= before + 3, 5.0)
        assert not any(r.msg.get_type() in ("SET_MODE", "COMMAND_LONG") and getattr(r.msg, "command", 0) in (176, 400)
                       for r in ap.from_service.items)  # never changes modes, never arms
    finally:
        rig.close()


def test_status_query_reports_counters(rig: Rig) -> None:
    assert rig.service.worker.health.wait_for(lambda h: h.frames >= 3, 5.0)
    status = rig.service.status()
    assert status["status"] == "ok" and status["source"]["frames"] >= 3
    assert status["config"]["mavlink"]["component_id"] == 100
    assert math.isfinite(status["uptime_s"])
    # every counter the daemon reports is explained in the demo's summary (sim.summary)
    from sim.summary import CAMERA_COMMAND_KEYS, COUNTER_MEANINGS
    assert set(status["counters"]) <= set(COUNTER_MEANINGS) | CAMERA_COMMAND_KEYS


def test_follow_target_mode_streams_geo_status_and_announces_it(frames_dir: Path) -> None:
    """276 is IDLE (lat, lon 0: nothing to read) until there is a ground estimate, also while the image
    track is active; ACTIVE with the target's position once the vehicle's position, attitude and the
    gimbal's attitude are known."""
    rig = Rig({"source": {"path": str(frames_dir), "loop": True},
               "guidance": {"mode": "follow_target", "rate_hz": 20.0}})
    try:
        assert rig.service.status()["autopilot"]["state"] == "connected"
        geo = lambda: [r.msg for r in rig.gcs.received.of("CAMERA_TRACKING_GEO_STATUS")]  # noqa: E731
        assert rig.gcs.received.wait_for(lambda: len(geo()) >= 3, 5.0)
        assert geo()[-1].tracking_status == 0  # idle: no estimate yet
        rig.gcs.command_long(REQUEST, [259, 0, 0, 0, 0, 0, 0], target=CAM)
        assert rig.gcs.received.wait_for(lambda: any(r.msg.get_srcSystem() == AP_SYSID
                                                     for r in rig.gcs.received.of("CAMERA_INFORMATION")), 5.0)
        info = [r.msg for r in rig.gcs.received.of("CAMERA_INFORMATION") if r.msg.get_srcSystem() == AP_SYSID][-1]
        assert info.flags & 2048  # HAS_TRACKING_GEO_STATUS
        # tracking, but the autopilot has sent no position: still idle, never ACTIVE at 0, 0
        rig.gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(TRACK_RECT, 0).result == ACCEPTED and rig.wait_tracking()
        seen = len(geo())
        assert rig.gcs.received.wait_for(lambda: len(geo()) >= seen + 10, 5.0)
        assert all(m.tracking_status == 0 and m.lat == 0 and m.lon == 0 for m in geo()[seen:])
        # the vehicle's position and attitude, and a gimbal looking 45 degrees down: an estimate exists
        down = [math.cos(math.radians(-22.5)), 0.0, math.sin(math.radians(-22.5)), 0.0]
        rig.autopilot.extra_periodic += [
            lambda mav: mav.global_position_int_encode(0, 473_977_420, 85_455_940, 520_000, 30_000, 0, 0, 0, 0),
            lambda mav: mav.attitude_encode(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            lambda mav: mav.gimbal_device_attitude_status_encode(0, 0, 0, 0, down, NAN, NAN, NAN, 0)]
        assert rig.gcs.received.wait_for(lambda: any(m.tracking_status == 1 for m in geo()), 5.0)
        active = [m for m in geo() if m.tracking_status == 1][-1]
        assert abs(active.lat - 473_977_420) < 10_000 and abs(active.lon - 85_455_940) < 10_000  # within ~100 m
        assert 0.0 < active.dist < 100.0
    finally:
        rig.close()


def test_waiting_for_the_autopilots_heartbeat_is_logged_and_reported(frames_dir: Path, caplog) -> None:
    """Until the autopilot's heartbeat arrives no gimbal command can go out (no system id to send to):
    the log says so once at start, and the status query reports it until the heartbeat comes."""
    import logging
    caplog.set_level(logging.INFO, logger="service")
    service_port, gcs_port = free_udp_ports(2)
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=AP_SYSID)
    autopilot.heartbeats_on = False
    autopilot.start()
    running = RunningService(Service(service_config(service_port, {"source": {"path": str(frames_dir), "loop": True}}))).start()
    service: Service = running.service  # type: ignore[assignment]
    try:
        assert service.worker.health.wait_for(lambda h: h.frames >= 3, 5.0)
        assert service.status()["autopilot"]["state"] == "waiting_for_heartbeat"
        assert service.status()["autopilot"]["gimbal_attitude_heard"] is False  # this peer has no gimbal device
        waiting = [r for r in caplog.records if "waiting for the autopilot's heartbeat" in r.getMessage()]
        assert len(waiting) == 1 and "gimbal and guidance commands are held" in waiting[0].getMessage()
        autopilot.heartbeats_on = True
        assert autopilot.from_service.wait_for(lambda: service.status()["autopilot"]["state"] == "connected", 5.0)
        autopilot.heartbeats_on = False
        assert autopilot.from_service.wait_for(lambda: service.status()["autopilot"]["state"] == "heartbeat_lost", 5.0)
        assert len([r for r in caplog.records if "waiting for the autopilot's heartbeat" in r.getMessage()]) == 1
    finally:
        running.stop()
        autopilot.close()


def test_serial_link_to_the_autopilot(frames_dir: Path) -> None:
    """mavlink.url as a serial device (a pseudo-terminal here): heartbeats go out, commands come in."""
    import os
    import select

    from pymavlink.dialects.v20 import common as dialect

    master, slave = os.openpty()
    config = service_config(0, {"source": {"path": str(frames_dir), "loop": True},
                                "mavlink": {"url": os.ttyname(slave), "baud": 115200, "system_id": 1}})
    running = RunningService(Service(config)).start()
    parser = dialect.MAVLink(None)
    parser.robust_parsing = True
    gcs = dialect.MAVLink(None, srcSystem=255, srcComponent=190)
    seen: list[object] = []

    def read_until(predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                seen.extend(m for m in parser.parse_buffer(os.read(master, 4096)) or [] if m.get_type() != "BAD_DATA")
                if predicate():
                    return True
        return False
    try:
        assert read_until(lambda: any(m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 100 for m in seen), 10.0)
        os.write(master, gcs.command_long_encode(1, 100, REQUEST, 0, 259, 0, 0, 0, 0, 0, 0).pack(gcs))
        assert read_until(lambda: any(m.get_type() == "COMMAND_ACK" and m.command == REQUEST for m in seen), 10.0)
    finally:
        running.stop()
        os.close(master)
        os.close(slave)


def test_px4_backend_claims_the_gimbal_then_sends_angular_velocities(frames_dir: Path) -> None:
    rig = Rig({"source": {"path": str(frames_dir), "loop": True}, "gimbal": {"backend": "px4"}},
              autopilot_kwargs={"autopilot": 12})
    ap = rig.autopilot
    ap.gimbal_primary = (0, 0)  # nobody in control yet
    try:
        assert rig.gcs.received.wait_for(lambda: rig.service.camera.autopilot_alive(), 5.0)
        rig.gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(TRACK_RECT, 0).result == ACCEPTED

        def of(kind: str) -> list:
            return [r.msg for r in ap.from_service.of(kind)]
        assert ap.from_service.wait_for(lambda: len(of("GIMBAL_MANAGER_SET_ATTITUDE")) >= 5, 10.0)
        claim = [m for m in of("COMMAND_LONG") if m.command == 1001][0]
        assert (claim.param1, claim.param2, claim.target_system, claim.target_component) == (AP_SYSID, 100, AP_SYSID, 1)
        assert ap.gimbal_primary == (AP_SYSID, 100)
        rates = of("GIMBAL_MANAGER_SET_ATTITUDE")[-1]
        assert all(math.isnan(q) for q in rates.q)
        assert rates.angular_velocity_z > 0 and rates.angular_velocity_y > 0  # target right of and above centre
        assert of("GIMBAL_MANAGER_SET_PITCHYAW") == []  # PX4 ignores 287: not sent
    finally:
        rig.close()


def test_frame_size_change_is_announced_and_tracking_continues(tmp_path: Path) -> None:
    for i in range(75):  # 2.5 s at 160x120, then the camera switches to 320x240
        cv2.imwrite(str(tmp_path / f"a{i:04d}.png"), scene((160, 120), (110, 40), 20))
    for i in range(30):
        cv2.imwrite(str(tmp_path / f"b{i:04d}.png"), scene((320, 240), (220, 80), 40))
    rig = Rig({"source": {"path": str(tmp_path), "loop": False}})
    try:
        rig.gcs.command_long(TRACK_RECT, [100 / 160, 30 / 120, 120 / 160, 50 / 120, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(TRACK_RECT, 0).result == ACCEPTED
        sizes = lambda: {(r.msg.resolution_h, r.msg.resolution_v) for r in rig.gcs.received.of("CAMERA_INFORMATION")}  # noqa: E731
        assert rig.gcs.received.wait_for(lambda: (320, 240) in sizes(), 10.0)
        assert rig.service.worker.health.wait_for(lambda h: h.state == "ended", 10.0)
        assert rig.service.loop.counters["resized"] == 1
        assert rig.service.loop.state in ("tracking", "recovered")
        x, y, w, h = rig.service.loop.box
        assert abs(x + w / 2 - 220) < 10 and abs(y + h / 2 - 80) < 10
    finally:
        rig.close()


def test_repeated_refusals_warn_once_per_kind_and_source() -> None:
    from service.mavlink.camera import RepeatedRefusals

    refusals = RepeatedRefusals()
    assert refusals.first(512, 260.0, (245, 190), 3)
    assert not refusals.first(512, 260.0, (245, 190), 3)  # the same poll again
    assert refusals.first(512, 261.0, (245, 190), 3)  # another message id is another kind
    assert refusals.first(512, 260.0, (245, 191), 3)  # another source
    assert refusals.first(527, 0.0, (245, 190), 3) and not refusals.first(527, 5.0, (245, 190), 3)
    assert refusals.first(2005, 0.5, (245, 190), 2) and not refusals.first(2005, 0.7, (245, 190), 2)
    assert refusals.first(512, NAN, (245, 190), 3) and not refusals.first(512, NAN, (245, 190), 3)

    for _ in range(3):
        refusals.count(512, 260.0, 3, "this camera does not provide message 260")
    refusals.count(2005, 0.5, 2, "rectangle inverted")
    assert refusals.summary() == [
        {"result": "UNSUPPORTED", "command": 512, "message": 260, "count": 3,
         "reason": "this camera does not provide message 260"},
        {"result": "DENIED", "command": 2005, "message": None, "count": 1, "reason": "rectangle inverted"}]
    for message in range(1000, 1100):  # junk from a peer: the kinds counted stay bounded
        refusals.count(512, float(message), 3, "junk")
    assert len(refusals.summary()) == RepeatedRefusals.MAX_KINDS


def test_a_polled_unsupported_request_is_answered_every_time_but_warned_once(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
    assert rig.gcs.received.wait_for(lambda: rig.service.link.system_id == AP_SYSID, 5.0)
    caplog.set_level("DEBUG", logger="service.mavlink")
    for index in range(3):  # what mavsdk's camera plugin does with CAMERA_SETTINGS (260)
        rig.gcs.command_long(REQUEST, [260, 0, 0, 0, 0, 0, 0], target=CAM)
        assert rig.gcs.wait_ack(REQUEST, index).result == 3  # UNSUPPORTED, every time
    # The camera logs a command before it sends the ACK: all three are in by now.
    refusals = [r for r in caplog.records if "message 260" in r.getMessage()]
    assert [r.levelname for r in refusals] == ["WARNING", "DEBUG", "DEBUG"]
    counters = rig.service.status()["counters"]
    assert counters["mavlink_rejected"] >= 3 and counters["mavlink_rejected_unsupported"] >= 3
    assert counters["mavlink_rejected"] == sum(counters[f"mavlink_rejected_{kind}"]
                                               for kind in ("unsupported", "denied", "temporarily", "failed"))
    (polled,) = [r for r in rig.service.status()["mavlink_refusals"] if r["message"] == 260]
    assert (polled["result"], polled["command"], polled["count"]) == ("UNSUPPORTED", REQUEST, 3)
    assert "does not provide message 260" in polled["reason"]


def test_a_different_refusal_from_the_same_sender_is_not_hidden_as_a_repeat() -> None:
    from service.mavlink.camera import RepeatedRefusals

    refusals = RepeatedRefusals()
    nan_reason = "top_left_x must be a finite number, got nan"
    assert refusals.first(2005, NAN, (255, 190), DENIED, nan_reason)
    assert not refusals.first(2005, NAN, (255, 190), DENIED, nan_reason)  # the same command, same reason
    inverted = "rectangle (0.5, 0.5)-(0.2, 0.6) is inverted or has zero size"
    assert refusals.first(2005, 0.5, (255, 190), DENIED, inverted)  # same sender and result, another reason
    assert not refusals.first(2005, 0.5, (255, 190), DENIED, inverted)
    for index in range(RepeatedRefusals.MAX_SEEN + 10):  # a junk flood: memory stays bounded ...
        refusals.first(2005, 0.5, (255, 190), DENIED, f"junk {index}")
    assert refusals.first(2005, 0.5, (255, 190), DENIED, "junk 1030")  # ... and past it, each is warned


def test_selection_without_a_frame_yet_is_temporarily_rejected_and_a_failing_source_fails() -> None:
    from service.mavlink.camera import selection_refusal

    assert selection_refusal("ok", True, "source ok") is None
    waiting = selection_refusal("starting", False, "source starting: opened, waiting for the first frame")
    assert waiting.result == 1 and "no camera frame yet" in waiting.reason  # TEMPORARILY_REJECTED
    assert selection_refusal("starting", False, "reopened").result == 1  # reopened after a fault: no frame yet
    assert selection_refusal("error", False, "source error: cannot open").result == FAILED
    assert selection_refusal("error", False, "source error: no frame for 2.0 s").result == FAILED
    assert selection_refusal("ended", False, "source ended: end of stream").result == FAILED


def test_refusals_are_logged_with_the_message_they_came_in_and_each_new_reason_is_warned(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
    assert rig.service.worker.health.wait_for(lambda h: h.state == "ok", 5.0)
    caplog.set_level("DEBUG", logger="service.mavlink")
    rig.gcs.command_long(TRACK_RECT, [NAN, 0.2, 0.3, 0.4, 0, 0, 0], target=CAM)
    assert rig.gcs.wait_ack(TRACK_RECT, 0).result == DENIED
    rig.gcs.command_long(TRACK_RECT, [0.5, 0.5, 0.2, 0.6, 0, 0, 0], target=CAM)  # inverted, same sender
    assert rig.gcs.wait_ack(TRACK_RECT, 1).result == DENIED
    rig.gcs.command_int(TRACK_RECT, 0.5, 0.5, 0.2, 0.6, 0, 0, 0, target=CAM)  # the same refusal again
    assert rig.gcs.wait_ack(TRACK_RECT, 2).result == DENIED
    # The camera logs a command before it sends the ACK: all three are in by now.
    refused = [r for r in caplog.records if "event=command command=2005" in r.getMessage()]
    assert [(r.levelname, r.getMessage().split(" via=")[1].split()[0]) for r in refused] == [
        ("WARNING", "COMMAND_LONG"), ("WARNING", "COMMAND_LONG"), ("DEBUG", "COMMAND_INT")]
    assert "finite number" in refused[0].getMessage() and "inverted" in refused[1].getMessage()


def test_wanted_autopilot_streams_are_asked_for_when_silent_or_slow_and_not_more_often_than_the_retry_time() -> None:
    # ArduPilot streams nothing on a companion port (SRn_ rates 0) until asked, and forgets on reboot;
    # PX4's onboard link sends GIMBAL_MANAGER_STATUS every 2-3 s
    from service.mavlink.autopilot import STREAM_RETRY_S, WANTED_STREAMS_HZ, stream_late_s, streams_to_request

    assert sorted(streams_to_request({}, {}, 100.0)) == sorted(WANTED_STREAMS_HZ)  # never heard: ask for all
    heard = {msg_id: 99.9 for msg_id in WANTED_STREAMS_HZ}
    assert streams_to_request(heard, {}, 100.0) == []  # all arriving: ask for nothing
    heard[281] = 100.0 - stream_late_s(WANTED_STREAMS_HZ[281]) - 0.1  # too slow (or stopped: a reboot)
    assert streams_to_request(heard, {}, 100.0) == [281]
    assert streams_to_request(heard, {281: 99.0}, 100.0) == []  # asked a moment ago: wait
    assert streams_to_request(heard, {281: 100.0 - STREAM_RETRY_S - 0.1}, 100.0) == [281]  # ask again
    assert stream_late_s(10.0) == 0.6 and stream_late_s(1.0) == 3.0
