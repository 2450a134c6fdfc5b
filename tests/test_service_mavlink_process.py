"""The daemon as a process on loopback MAVLink: result codes before the first frame, and MAVLink 2 signing
end to end (a key from `jsar-service keygen`, signed / unsigned / wrong-key / replayed commands, counted in
the status query; MAVProxy's own signing against it where MAVProxy is installed)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest
import yaml

from service.sources.zenoh_wire import encode_frame
from tests.conftest import free_tcp_port, free_udp_port
from tests.service_peers import AutopilotPeer, GroundStation
from tests.test_service_sources import scene

REPO = Path(__file__).resolve().parents[1]
AP_SYSID = 9
CAM = (AP_SYSID, 100)
TRACK_RECT, STOP, INTERVAL = 2005, 2010, 511
ACCEPTED, TEMPORARILY_REJECTED = 0, 1


class Daemon:
    """`python -m service` with a written config, its stderr collected; stop() ends it by its pid."""

    def __init__(self, tmp_path: Path, config: dict) -> None:
        config_file = tmp_path / "config.yaml"
        config_file.write_text(yaml.safe_dump(config))
        self.proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(config_file)], cwd=REPO,
                                     env={**os.environ, "MAVLINK20": "1"}, stderr=subprocess.PIPE, text=True)

    def stop(self) -> str:
        """SIGTERM, wait, and the daemon's log."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.stderr.read() if self.proc.stderr else ""


def daemon_config(service_port: int, zenoh_port: int, source: dict, mavlink: dict | None = None) -> dict:
    """A daemon config: csrt, Zenoh listening on loopback only (prefix `proc`), no preview."""
    return {"source": {"retry_initial_s": 0.05, "retry_max_s": 0.2, **source},
            "tracker": {"name": "csrt", "range_size_band": 0},
            "mavlink": {"url": f"udpout:127.0.0.1:{service_port}", "system_id": AP_SYSID, **(mavlink or {})},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "proc"},
            "video": {"preview": {"enabled": False}},
            "logging": {"level": "DEBUG"}}


def zenoh_peer(port: int) -> object:
    """A Zenoh peer connected to the daemon's listen endpoint only (no multicast scouting)."""
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(config)


def query_status(session: object, timeout_s: float = 20.0) -> dict:
    """The daemon's status query answer (retried until the Zenoh connection is up)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        replies = list(session.get("proc/status", timeout=1.0))
        if replies and replies[0].ok is not None:
            return json.loads(replies[0].ok.payload.to_string())
    raise AssertionError(f"no answer to proc/status within {timeout_s} s")


def camera_heartbeat(gcs: GroundStation, timeout_s: float) -> bool:
    """The camera's HEARTBEAT (system AP_SYSID, component 100) arrived through the autopilot peer."""
    return gcs.received.wait_for(lambda: any(r.msg.get_srcComponent() == 100 and r.msg.get_srcSystem() == AP_SYSID
                                             for r in gcs.received.of("HEARTBEAT")), timeout_s)


@pytest.fixture
def peers() -> Iterator[tuple[AutopilotPeer, int, int]]:
    """An autopilot peer (system AP_SYSID) between the daemon's port and a ground-station port."""
    service_port, gcs_port = free_udp_port(), free_udp_port()
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=AP_SYSID).start()
    yield autopilot, service_port, gcs_port
    autopilot.close()


def test_a_selection_before_the_first_frame_is_temporarily_rejected_then_accepted(
        tmp_path: Path, peers: tuple[AutopilotPeer, int, int]) -> None:
    """The camera's heartbeat goes out before the first frame: a ground station that selects at once is
    told TEMPORARILY_REJECTED (retry), with the reason as STATUSTEXT, and its retry once frames flow is
    ACCEPTED."""
    _, service_port, gcs_port = peers
    zenoh_port = free_tcp_port()
    daemon = Daemon(tmp_path, daemon_config(service_port, zenoh_port, {"kind": "zenoh"}))
    gcs = GroundStation(gcs_port).start()
    session = None
    try:
        assert camera_heartbeat(gcs, 60.0), "no camera heartbeat"
        gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)
        ack = gcs.wait_ack(TRACK_RECT, 0)
        assert ack is not None and ack.result == TEMPORARILY_REJECTED, ack
        text = "".join(r.msg.text for r in gcs.received.of("STATUSTEXT"))  # one text in 50-character chunks
        assert text.startswith("TRACK_RECTANGLE TEMPORARILY_REJECTED: no camera frame yet"), text
        session = zenoh_peer(zenoh_port)
        status = query_status(session)
        assert status["source"]["state"] == "starting" and status["track"]["state"] == "idle"
        assert status["counters"]["mavlink_rejected_temporarily"] == 1
        publisher = session.declare_publisher("proc/camera/frame")
        image = scene((160, 120), (110, 40), 20)
        frame_id = 0
        while query_status(session)["source"]["frames"] == 0:  # until the daemon's subscription is matched
            assert frame_id < 400, "no frame reached the daemon"
            publisher.put(encode_frame(image, frame_id, time.time()))
            frame_id += 1
        gcs.command_long(TRACK_RECT, [0.55, 0.2, 0.8, 0.5, 0, 0, 0], target=CAM)  # the ground station retries
        ack = gcs.wait_ack(TRACK_RECT, 1)
        assert ack is not None and ack.result == ACCEPTED, ack
    finally:
        if session is not None:
            session.close()
        gcs.close()
        log = daemon.stop()
    assert "Traceback" not in log
    assert "result=TEMPORARILY_REJECTED" in log and "via=COMMAND_LONG" in log
