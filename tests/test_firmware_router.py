"""One autopilot link, as on a real drone, through MAVProxy as the output router (issue 46).

ArduCopter SITL's SERIAL0 feeds MAVProxy (mavproxy==1.8.75 from the package index, in its own
environment: `make mavproxy`, or JSAR_MAVPROXY naming another mavproxy.py), whose outputs serve the
companion computer (the daemon, through a wire tap) and a ground station (pymavlink, the test).

What the firmware and MAVProxy show: traffic between the autopilot and each output passes both ways
(the daemon hears the autopilot and ArduPilot answers the daemon's stream requests; the ground station
hears the autopilot, whose answer to a track command addressed to it is UNSUPPORTED). Traffic between
the two outputs does not: MAVProxy forwards what an output sends to its master only (mavproxy.py,
process_mavlink), and ArduPilot never sends a message back out of the port it came in on. So the
camera's heartbeat never reaches the ground station, and the ground station's track command never
reaches the camera: ArduPilot answers it UNSUPPORTED itself, as if the camera could not track. The
topology that works is ArduPilot's own routing, the camera on one serial port and the ground station
on another (tests/test_firmware_ardupilot.py), or a router that forwards between its endpoints
(mavlink-router); docs/deploy.md. This test fails when MAVProxy starts routing between its outputs, so
that the docs can say so."""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")

from sim.firmware import ArduPilotSitl  # noqa: E402
from sim.ports import free_tcp_port, free_udp_ports  # noqa: E402
from tests.firmware_peers import (REPO, TRACK_RECTANGLE, DaemonProcess, FramePump, Station, WireTap,  # noqa: E402
                                  target_rectangle, terminate)
from tests.helpers import require  # noqa: E402

MAVPROXY = Path(os.environ.get("JSAR_MAVPROXY", REPO / ".venv-mavproxy" / "bin" / "mavproxy.py"))
AUTOPILOT, CAMERA = (1, 1), (1, 100)


pytestmark = pytest.mark.firmware("arducopter")  # real firmware processes, 10-30 s a test


@pytest.fixture(autouse=True)
def _mavproxy() -> None:
    require(None if MAVPROXY.exists() else
            f"MAVProxy is not installed at {MAVPROXY} (`make mavproxy`; JSAR_MAVPROXY names another)")


class MavProxyRouter:
    """MAVProxy with one master (the autopilot's port) and UDP outputs, no modules, no console; its
    output in workdir/mavproxy.log. Stopped by its PID."""

    def __init__(self, master: str, outputs: list[str], workdir: Path) -> None:
        workdir.mkdir(parents=True, exist_ok=True)
        self.log_path = workdir / "mavproxy.log"
        argv = [str(MAVPROXY), f"--master={master}", *[f"--out={out}" for out in outputs], "--mav20",
                "--daemon", "--non-interactive", "--default-modules=", "--source-system=254",
                f"--state-basedir={workdir}"]
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(argv, cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL,
                                            env={**os.environ, "MAVLINK20": "1", "HOME": str(workdir)})

    def close(self) -> None:
        terminate(self.process, 10.0)

    def log_tail(self) -> str:
        return self.log_path.read_text(errors="replace")[-1500:]


def test_mavproxy_routes_autopilot_traffic_to_each_output_but_not_between_camera_and_ground_station(
        tmp_path: Path) -> None:
    with ArduPilotSitl(links=1) as firmware:
        (gcs_port, tap_port, daemon_port), zenoh_port = free_udp_ports(3), free_tcp_port()
        router = MavProxyRouter(f"udpin:127.0.0.1:{firmware.ports[0]}",
                                [f"udpout:127.0.0.1:{tap_port}", f"udpout:127.0.0.1:{gcs_port}"], tmp_path / "mavproxy")
        gcs = Station(f"udpin:127.0.0.1:{gcs_port}").start()
        tap = WireTap(tap_port, daemon_port).start()
        camera = FramePump(zenoh_port, "routerfw").start()
        daemon = DaemonProcess(tmp_path, zenoh_port, "routerfw", f"udpin:127.0.0.1:{daemon_port}",
                               {"gimbal": {"backend": "ardupilot"}}).__enter__()
        try:
            def diagnostics() -> str:
                return f"MAVProxy:\n{router.log_tail()}\ndaemon:\n{daemon.log_tail()}"

            # the ground station hears the autopilot through MAVProxy
            assert gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and (m.get_srcSystem(), m.get_srcComponent())
                            == AUTOPILOT, 60.0) is not None, diagnostics()
            # the daemon hears it too, and ArduPilot answers the daemon's requests (its stream requests,
            # COMMAND_ACK addressed to the camera) through MAVProxy
            assert tap.to_daemon.wait_for(lambda: any(
                r.msg.get_type() == "COMMAND_ACK" and r.msg.command == 511 and r.msg.result == 0
                and (r.msg.target_system, r.msg.target_component) == CAMERA for r in tap.to_daemon.items), 30.0), \
                diagnostics()
            assert tap.to_daemon.wait_for(lambda: bool(tap.to_daemon.of("GIMBAL_DEVICE_ATTITUDE_STATUS")), 10.0)
            assert tap.from_daemon.of("HEARTBEAT"), "the camera sent no heartbeat"
            # the autopilot has no tracking camera of its own: UNSUPPORTED
            assert gcs.command(AUTOPILOT, TRACK_RECTANGLE, target_rectangle() + [0]).result == 3
            # between the outputs nothing passes: no camera heartbeat at the ground station, and its track
            # command for the camera never reaches the daemon: the autopilot answers UNSUPPORTED in its place
            since = time.monotonic()
            assert gcs.wait(lambda m: m.get_srcComponent() == CAMERA[1], 5.0) is None
            asked = time.monotonic()
            gcs.send(lambda mav: mav.command_long_encode(*CAMERA, TRACK_RECTANGLE, 0, *target_rectangle(), 0, 0, 0))
            ack = gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == TRACK_RECTANGLE, 3.0, asked)
            # ArduPilot, which does not send it back to the port the camera is on, answers it itself
            assert ack is not None and (ack.get_srcSystem(), ack.get_srcComponent()) == AUTOPILOT and ack.result == 3
            assert gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == TRACK_RECTANGLE
                            and m.get_srcComponent() == CAMERA[1], 2.0, asked) is None
            assert not [r for r in tap.to_daemon.items if r.at >= since and r.msg.get_type() == "COMMAND_LONG"
                        and r.msg.command == TRACK_RECTANGLE]
            assert len(tap.from_daemon.of("HEARTBEAT")) >= 5  # the camera was beating all along
        finally:
            daemon.__exit__(None, None, None)
            for close in (camera.close, tap.close, gcs.close, router.close):
                close()
