"""The ground side on a bench with only the camera on the link: the daemon on an image folder, no autopilot,
the ground station listening for it (udpin).

- The mavsdk command-line ground station (gcs.cli): every subcommand works against the camera component
  alone; a link with nothing on it, or no such system, ends with a one-line error.
- The web station's MAVLink side (gcs.mavlink_station): commands acknowledged, a refusal with the
  camera's reason (a chunked STATUSTEXT), 275 on request, no ACK reported as such."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
import yaml

from sim.ports import free_udp_port
from tests.test_service_sources import scene

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MAVLINK20": "1", "PYTHONUNBUFFERED": "1"}


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory):
    """The daemon alone (image folder, no autopilot), sending MAVLink to a port the CLI listens on."""
    folder = tmp_path_factory.mktemp("gcs_cli")
    frames = folder / "frames"
    frames.mkdir()
    for i in range(20):
        cv2.imwrite(str(frames / f"{i:04d}.png"), scene((160, 120), (100 - i, 50), 20))
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    config["tracker"].update({"name": "csrt", "range_size_band": 0})  # fast; csrt has no side bounds
    config["zenoh"]["enabled"] = False
    config["source"]["loop"] = True
    (folder / "config.yaml").write_text(yaml.safe_dump(config))
    port = free_udp_port()
    log = open(folder / "daemon.log", "w")
    daemon = subprocess.Popen([sys.executable, "-m", "service", "--config", str(folder / "config.yaml"),
                               "--source", str(frames), "--mavlink", f"udpout:127.0.0.1:{port}"],
                              cwd=REPO, env=ENV, stdout=log, stderr=subprocess.STDOUT)
    try:
        yield port
    finally:
        daemon.terminate()
        daemon.wait(timeout=10)
        log.close()


def cli(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """Run `python -m gcs.cli ARGS` (what the jsar-gcs console script runs)."""
    return subprocess.run([sys.executable, "-m", "gcs.cli", *args], cwd=REPO, env=ENV, capture_output=True,
                          text=True, timeout=timeout_s)


def test_every_subcommand_works_with_the_camera_alone(bench: int) -> None:
    url = f"udpin://127.0.0.1:{bench}"
    listed = cli("--url", url, "--timeout", "30", "list")  # the first run also waits for the daemon's start
    assert listed.returncode == 0, listed.stderr
    assert "camera only, no autopilot heard" in listed.stdout
    assert "camera component 100: JSAR jsar-tracker 160x120" in listed.stdout

    selected = cli("--url", url, "rect", "0.5", "0.3", "0.75", "0.55", "--watch", "1.5", "--interval", "0.2")
    assert selected.returncode == 0, selected.stderr
    assert "track_rectangle: SUCCESS" in selected.stdout
    assert "ACTIVE   mode 2" in selected.stdout  # the 275 status the CLI asked for, while tracking

    status = cli("--url", url, "status", "--watch", "1.0", "--interval", "0.2")
    assert status.returncode == 0 and "camera 100: ACTIVE" in status.stdout, status.stdout + status.stderr

    pointed = cli("--url", url, "point", "0.3", "0.4")
    assert pointed.returncode == 0 and "track_point: SUCCESS" in pointed.stdout, pointed.stderr

    stopped = cli("--url", url, "stop", "--watch", "1.5", "--interval", "0.2")
    assert stopped.returncode == 0 and "track_stop: SUCCESS" in stopped.stdout, stopped.stderr
    assert "camera 100: IDLE" in stopped.stdout
    for run in (listed, selected, status, pointed, stopped):
        assert "Traceback" not in run.stderr, run.stderr


def test_a_refused_command_is_one_line_and_exit_1(bench: int) -> None:
    url = f"udpin://127.0.0.1:{bench}"
    refused = cli("--url", url, "--timeout", "30", "point", "2", "2")  # outside 0..1: the camera denies it
    assert refused.returncode == 1
    assert refused.stderr.strip().splitlines()[-1] == "rejected: track_point() answered DENIED"
    assert "Traceback" not in refused.stderr


def test_nothing_on_the_link_is_a_clear_error_without_traceback() -> None:
    silent = cli("--url", f"udpin://127.0.0.1:{free_udp_port()}", "--timeout", "1", "list")
    assert silent.returncode == 2
    assert "Traceback" not in silent.stderr
    assert silent.stderr.strip().startswith("jsar-gcs: no MAVLink system heard on udpin://127.0.0.1:")


def test_an_absent_system_names_what_was_heard(bench: int) -> None:
    url = f"udpin://127.0.0.1:{bench}"
    absent = cli("--url", url, "--timeout", "3", "--system", "7", "list")
    assert absent.returncode == 2 and "Traceback" not in absent.stderr
    assert "no system 7 with a camera" in absent.stderr and "heard: system 1 (components 100)" in absent.stderr


def test_web_station_mavlink_side_against_the_camera_alone(bench: int) -> None:
    from gcs.mavlink_station import MavlinkStation

    statuses = []
    station = MavlinkStation([f"udpin:127.0.0.1:{bench}"], on_status=statuses.append, ack_timeout_s=0.5)
    try:
        assert station.wait_for(lambda: (1, 100) in station.cameras(), 30.0), "the camera's heartbeat never came"
        denied = station.track_rectangle(1, 100, 0.5, 0.25, 0.25, 0.5)  # inverted: the camera refuses it
        assert denied.result_name == "DENIED" and denied.attempts == 1
        # longer than one STATUSTEXT: sent in chunks, reassembled
        assert denied.reason == "TRACK_RECTANGLE DENIED: rectangle (0.5, 0.25)-(0.25, 0.5) is inverted or has zero size"

        accepted = station.track_rectangle(1, 100, 0.5, 0.3, 0.75, 0.55)
        assert accepted.accepted and accepted.reason is None
        assert station.request_status(1, 100, interval_s=0.1, every_s=0.0).accepted
        assert station.wait_for(lambda: any(s.status == 1 for s in statuses), 5.0)
        assert station.status(1, 100).mode == 2  # RECTANGLE

        assert station.stop_tracking(1, 100).accepted
        assert station.wait_for(lambda: statuses[-1].status == 0, 5.0)

        silent = station.stop_tracking(1, 101)  # no such camera: nobody answers
        assert silent.result is None and silent.result_name == "NO_ACK" and silent.attempts == 3
    finally:
        station.close()

