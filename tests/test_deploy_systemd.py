"""deploy/jsar-service.service under a real systemd: PID 1 of a podman container built from the service
image with the unit installed as documented (deploy/systemd-check.Containerfile, `make check-systemd`).

It reaches `active (running)` through READY=1, the watchdog keeps it alive while frames flow (and it
answers the MAVLink handshake and tracks a selected target inside the sandbox), the hardening lets it
open camera and serial devices and blocks others, a hung loop (SIGSTOP) is restarted by the watchdog,
SIGKILL is restarted and comes back idle saying so, and `systemctl stop` ends it within 2 s. Runs only with JSAR_CHECK_SYSTEMD=1 (`make check-systemd`
builds the image and sets it): it needs root and a privileged container.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import uuid
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pytest

from sim.ports import free_tcp_port, free_udp_ports
from tests.deploy_helpers import (IMAGE, host_arch, podman, podman_limits, select_and_track, status, write_config,
                                  write_target_video, zenoh_session)
from tests.service_peers import AutopilotPeer, GroundStation, camera_handshake

pytestmark = [pytest.mark.slow, pytest.mark.skipif(os.environ.get("JSAR_CHECK_SYSTEMD") != "1",
                                                   reason="systemd check: run `make check-systemd` (root, podman)")]
UNIT = "jsar-service"
SYSTEM_ID = 5
PROBE = r"""
import errno, json, os
result = {}
for path in ("/dev/video0", "/dev/ttyS0", "/dev/ttyUSB0", "/dev/ttyACM0", "/dev/jsar-blocked"):
    try:
        os.close(os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_NOCTTY))
        result[path] = "opened"
    except OSError as exc:
        result[path] = errno.errorcode.get(exc.errno, str(exc.errno))
# the serial link as pymavlink opens it (pyserial: termios ioctls, baud rate), where the port opened
if result["/dev/ttyS0"] == "opened":
    import serial
    try:
        serial.Serial("/dev/ttyS0", 921600, timeout=0).close()
        result["pyserial /dev/ttyS0"] = "configured"
    except (OSError, serial.SerialException) as exc:
        result["pyserial /dev/ttyS0"] = repr(exc)[:120]
print("PROBE " + json.dumps(result))
"""
PROBE_DROPIN = """[Unit]
Description=device access probe in jsar-service's sandbox
[Service]
Type=oneshot
ExecStart=
ExecStart=/opt/jsar/.venv/bin/python /usr/local/lib/jsar-device-probe.py
WatchdogSec=0
Restart=no
"""


class Rig:
    """The systemd container plus the test's autopilot, ground station and Zenoh session on loopback."""

    def __init__(self, tmp: Path) -> None:
        self.name = f"jsar-systemd-check-{uuid.uuid4().hex[:8]}"
        (service_port, gcs_port), self.zenoh_port = free_udp_ports(2), free_tcp_port()
        video_dir, config_dir = tmp / "video", tmp / "etc"
        video_dir.mkdir()
        write_target_video(video_dir)
        write_config(config_dir, service_port, self.zenoh_port, "systemdcheck")
        self.autopilot = AutopilotPeer(service_port, gcs_port, system_id=SYSTEM_ID).start()
        self.gcs = GroundStation(gcs_port).start()
        self.session = None
        image = f"{IMAGE}-systemd:{host_arch()}"
        if podman("image", "exists", image).returncode != 0:
            pytest.fail(f"{image} is not built: run `make check-systemd`")
        # a private cgroup namespace: systemd then finds its own cgroup at the root of each v1 hierarchy
        # and applies the unit's device policy (without it DevicePolicy= silently does nothing here)
        run = podman("run", "-d", "--name", self.name, "--privileged", "--systemd=always", "--cgroupns=private",
                     "--network", "host",
                     *podman_limits(), "-v", f"{video_dir}:/data:ro", "-v", f"{config_dir}:/etc/jsar:ro", image)
        assert run.returncode == 0, run.stderr

    def run(self, *command: str, timeout: float = 60.0, stdin: str | None = None) -> subprocess.CompletedProcess:
        return subprocess.run(["podman", "exec", "-i", self.name, *command], input=stdin, capture_output=True,
                              text=True, timeout=timeout)

    def exec(self, *command: str, timeout: float = 60.0, stdin: str | None = None) -> str:
        proc = self.run(*command, timeout=timeout, stdin=stdin)
        assert proc.returncode == 0, f"{' '.join(command)}: {proc.stdout}{proc.stderr}"
        return proc.stdout

    def show(self, unit: str = UNIT) -> dict[str, str]:
        """The unit's properties; {} while systemd is not answering yet (booting)."""
        keys = "ActiveState,SubState,MainPID,NRestarts,Result,ExecMainStatus,ExecMainCode,WatchdogTimestampMonotonic"
        proc = self.run("systemctl", "show", unit, "-p", keys)
        return dict(line.split("=", 1) for line in proc.stdout.splitlines() if "=" in line) if proc.returncode == 0 else {}

    def wait_show(self, predicate: Callable[[dict[str, str]], bool], timeout_s: float) -> dict[str, str]:
        """Poll the unit's properties until predicate holds (AssertionError with the last ones on timeout)."""
        deadline = time.monotonic() + timeout_s
        while True:
            props = self.show()
            if props and predicate(props):
                return props
            assert time.monotonic() < deadline, f"unit state not reached within {timeout_s} s: {props}"
            time.sleep(0.2)  # polling interval of an external state (systemd has no event we can block on here)

    def journal(self, unit: str = UNIT) -> str:
        return self.exec("journalctl", "-u", unit, "--no-pager", "-o", "cat")

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
        self.gcs.close()
        self.autopilot.close()
        podman("rm", "--force", "--time", "5", self.name)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    if shutil.which("podman") is None:
        pytest.skip("podman is not installed")
    rig = Rig(tmp_path_factory.mktemp("systemd"))
    yield rig
    rig.close()


def test_reaches_active_running_through_ready(rig: Rig) -> None:
    # Type=notify: the unit stays "activating" until the daemon sends READY=1
    props = rig.wait_show(lambda p: p["ActiveState"] not in ("activating", "inactive"), 120.0)
    assert (props["ActiveState"], props["SubState"], props["NRestarts"]) == ("active", "running", "0"), props
    assert "Active: active (running)" in rig.exec("systemctl", "status", UNIT, "--no-pager")
    assert "event=started" in rig.journal()


def test_watchdog_keeps_it_alive_while_frames_flow_and_it_tracks(rig: Rig) -> None:
    first = rig.wait_show(lambda p: p["ActiveState"] == "active", 120.0)
    rig.session = zenoh_session(rig.zenoh_port)
    info = camera_handshake(rig.gcs, SYSTEM_ID, timeout_s=30.0)
    assert (info.resolution_h, info.resolution_v) == (320, 240)
    start_frames = None
    deadline = time.monotonic() + 60.0
    while start_frames is None and time.monotonic() < deadline:  # each get waits up to 1 s for the reply
        reply = status(rig.session, "systemdcheck")
        start_frames = None if reply is None else reply["source"]["frames"]
    assert start_frames is not None, "no status reply over Zenoh within 60 s"
    errors = select_and_track(rig.gcs, rig.session, "systemdcheck", SYSTEM_ID, frames_wanted=90, timeout_s=20.0)
    # at least three watchdog periods (WatchdogSec=5s) of pings, same process, no restart
    pings = {first["WatchdogTimestampMonotonic"]}
    began = time.monotonic()
    props = rig.wait_show(lambda p: bool(pings.add(p["WatchdogTimestampMonotonic"])) or
                          (len(pings) >= 6 and time.monotonic() - began > 15.0), 40.0)
    assert props["MainPID"] == first["MainPID"] and props["NRestarts"] == "0", props
    reply = status(rig.session, "systemdcheck")
    assert reply is not None and reply["source"]["frames"] > start_frames + 300, reply and reply["source"]
    print(f"\nwatchdog: {len(pings)} distinct ping timestamps in {time.monotonic() - began:.1f} s, "
          f"median centre error {np.median(errors):.1f} px over {len(errors)} frames tracked under systemd")


def test_hardening_allows_camera_and_serial_devices_and_blocks_others(rig: Rig) -> None:
    rig.exec("sh", "-c", "cat > /usr/local/lib/jsar-device-probe.py", stdin=PROBE)
    outside = json.loads(rig.exec("runuser", "-u", "jsar", "--", "/opt/jsar/.venv/bin/python",
                                  "/usr/local/lib/jsar-device-probe.py").split("PROBE ", 1)[1])
    rig.exec("sh", "-c", "cp /etc/systemd/system/jsar-service.service /etc/systemd/system/jsar-device-probe.service"
             " && mkdir -p /etc/systemd/system/jsar-device-probe.service.d"
             " && cat > /etc/systemd/system/jsar-device-probe.service.d/probe.conf && systemctl daemon-reload",
             stdin=PROBE_DROPIN)
    rig.exec("systemctl", "start", "jsar-device-probe", timeout=120.0)  # oneshot: returns when the probe exited
    line = [x for x in rig.journal("jsar-device-probe").splitlines() if x.startswith("PROBE ")][-1]
    inside = json.loads(line.split("PROBE ", 1)[1])
    print(f"\ndevice open results, user jsar outside the unit: {outside}\n  inside jsar-service's sandbox: {inside}")
    assert inside["/dev/jsar-blocked"] == "EPERM", \
        f"the unit's DevicePolicy is not enforced in this container (control device gave {inside['/dev/jsar-blocked']})"
    assert outside["/dev/jsar-blocked"] != "EPERM"
    for path in ("/dev/video0", "/dev/ttyS0", "/dev/ttyUSB0", "/dev/ttyACM0"):
        assert inside[path] not in ("EPERM", "EACCES"), f"{path} blocked in the unit: {inside[path]}"
        assert inside[path] == outside[path], (path, inside[path], outside[path])
    assert inside.get("pyserial /dev/ttyS0") == outside.get("pyserial /dev/ttyS0"), (inside, outside)


def test_a_hung_loop_is_restarted_by_the_watchdog(rig: Rig) -> None:
    before = rig.wait_show(lambda p: p["ActiveState"] == "active", 30.0)
    rig.exec("systemctl", "kill", "--signal=SIGSTOP", "--kill-whom=main", UNIT)  # the loop hangs: no more pings
    stopped = time.monotonic()
    after = rig.wait_show(lambda p: p["NRestarts"] == str(int(before["NRestarts"]) + 1)
                          and p["ActiveState"] == "active" and p["MainPID"] not in ("0", before["MainPID"]), 90.0)
    took = time.monotonic() - stopped
    journal = rig.journal()
    assert "Watchdog timeout" in journal, journal[-3000:]
    assert 5.0 <= took, f"restarted after {took:.1f} s: before WatchdogSec=5s ran out"
    print(f"\nSIGSTOP -> watchdog timeout -> restarted and READY again after {took:.1f} s (pid {before['MainPID']} -> "
          f"{after['MainPID']})")


def test_sigkill_restarts_it_idle_and_it_says_so(rig: Rig) -> None:
    """Fault (issue 42): SIGKILL to the daemon while it tracks. systemd restarts it (Restart=on-failure,
    RestartSec=2s); it comes back idle, and says so: the journal's event=restarted_after_unclean_exit and
    the status's run.previous_exit "unclean" (its run marker in RuntimeDirectory, kept across restarts); it
    zeroes the gimbal rates once, then sends nothing (idle)."""
    before = rig.wait_show(lambda p: p["ActiveState"] == "active", 60.0)
    if rig.session is None:
        rig.session = zenoh_session(rig.zenoh_port)
    select_and_track(rig.gcs, rig.session, "systemdcheck", SYSTEM_ID, frames_wanted=30, timeout_s=30.0)
    reply = status(rig.session, "systemdcheck")
    assert reply is not None and reply["track"]["state"] != "idle", reply and reply["track"]
    marks = len([line for line in rig.journal().splitlines() if "event=restarted_after_unclean_exit" in line])
    rig.exec("systemctl", "kill", "--signal=SIGKILL", "--kill-whom=main", UNIT)
    killed = time.monotonic()
    after = rig.wait_show(lambda p: p["NRestarts"] == str(int(before["NRestarts"]) + 1)
                          and p["ActiveState"] == "active" and p["MainPID"] not in ("0", before["MainPID"]), 60.0)
    active_s = time.monotonic() - killed
    reply = None
    while reply is None or reply["source"]["frames"] == 0:  # each get waits up to 1 s for the reply
        assert time.monotonic() - killed < 60.0, "no status from the restarted daemon within 60 s"
        reply = status(rig.session, "systemdcheck")
    status_s = time.monotonic() - killed
    journal = rig.journal()
    assert "status=9/KILL" in journal, journal[-3000:]
    unclean = [line for line in journal.splitlines() if "event=restarted_after_unclean_exit" in line]
    assert len(unclean) == marks + 1 and f"previous_pid={before['MainPID']} " in unclean[-1], unclean
    assert "track=idle" in unclean[-1]
    assert reply["run"]["previous_exit"] == "unclean" and reply["run"]["previous_pid"] == int(before["MainPID"])
    assert reply["track"]["state"] == "idle" and reply["track"]["box_px"] is None, reply["track"]
    # the killed run's last gimbal rate (ArduPilot's never time out) is cancelled once by the new run
    gimbal = "GIMBAL_MANAGER_SET_PITCHYAW"
    assert rig.autopilot.from_service.wait_for(
        lambda: any(r.at > killed + 0.5 for r in rig.autopilot.from_service.of(gimbal)), 10.0), "gimbal not zeroed"
    zeroed = [r.msg for r in rig.autopilot.from_service.of(gimbal) if r.at > killed + 0.5]
    assert len(zeroed) == 1 and (zeroed[0].yaw_rate, zeroed[0].pitch_rate) == (0.0, 0.0), zeroed
    assert "event=gimbal_zeroed reason=previous_run_killed" in rig.journal()
    print(f"\nSIGKILL while tracking -> restarted (pid {before['MainPID']} -> {after['MainPID']}) and READY after "
          f"{active_s:.1f} s (RestartSec=2s), status answering idle with previous_exit unclean after {status_s:.1f} s")


def test_systemctl_stop_ends_it_within_2s(rig: Rig) -> None:
    rig.wait_show(lambda p: p["ActiveState"] == "active", 60.0)
    begin, end = (float(v) for v in rig.exec("sh", "-c", "a=$(date +%s.%N); systemctl stop jsar-service; "
                                                   "b=$(date +%s.%N); echo $a $b").split())
    props = rig.show()
    assert props["ActiveState"] == "inactive" and props["Result"] == "success", props
    assert props["ExecMainCode"] == "1" and props["ExecMainStatus"] == "0", props  # exited 0, not killed
    assert end - begin < 2.0, f"systemctl stop took {end - begin:.2f} s"
    assert "event=stopped" in rig.journal()
    print(f"\nsystemctl stop returned after {end - begin:.2f} s; exit status 0")


def test_security_exposure_is_reported(rig: Rig) -> None:
    out = rig.exec("systemd-analyze", "security", "--no-pager", UNIT)
    overall = [line for line in out.splitlines() if "Overall exposure level" in line]
    assert overall, out[-2000:]
    print("\n" + overall[0])
