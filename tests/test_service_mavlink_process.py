"""The daemon as a process on loopback MAVLink: result codes before the first frame, and MAVLink 2 signing
end to end (a key from `jsar-service keygen`, signed / unsigned / wrong-key / replayed commands, counted in
the status query; MAVProxy's own signing against it where MAVProxy is installed)."""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest
import yaml

from bench.fuzz import zenoh_session
from service.sources.zenoh_wire import encode_frame
from sim.ports import free_tcp_port, free_udp_ports
from tests.helpers import write_square_frames
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
    service_port, gcs_port = free_udp_ports(2)
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
        session = zenoh_session(zenoh_port)
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


# --- signing ----------------------------------------------------------------------------------------
def keygen(out: Path, *extra: str) -> subprocess.CompletedProcess:
    """`python -m service keygen --out OUT ...` (what `jsar-service keygen` runs)."""
    return subprocess.run([sys.executable, "-m", "service", "keygen", "--out", str(out), *extra], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def test_keygen_writes_a_0600_key_of_a_printed_passphrase_and_refuses_to_overwrite(tmp_path: Path) -> None:
    import hashlib

    key_file = tmp_path / "mavlink.key"
    made = keygen(key_file)
    assert made.returncode == 0, made.stderr
    passphrase = made.stdout.split("signing key): ")[1].strip()
    assert len(passphrase) == 43 and passphrase.isascii() and " " not in passphrase  # 32 random bytes, base64
    assert key_file.stat().st_mode & 0o777 == 0o600
    key = bytes.fromhex(key_file.read_text().strip())
    assert key == hashlib.sha256(passphrase.encode("ascii")).digest()  # what MAVProxy / QGroundControl derive
    again = keygen(key_file)
    assert again.returncode == 1 and "exists; --force replaces it" in again.stderr
    assert bytes.fromhex(key_file.read_text().strip()) == key  # untouched
    key_file.chmod(0o644)
    forced = keygen(key_file, "--force")
    assert forced.returncode == 0 and forced.stdout.split("signing key): ")[1].strip() != passphrase
    assert bytes.fromhex(key_file.read_text().strip()) != key and key_file.stat().st_mode & 0o777 == 0o600
    phrase_file = tmp_path / "fleet.passphrase"
    phrase_file.write_text("fleet-passphrase-1\n")
    derived = keygen(tmp_path / "fleet.key", "--passphrase-file", str(phrase_file))
    assert derived.returncode == 0 and "passphrase for" not in derived.stdout  # nothing new to hand out
    assert bytes.fromhex((tmp_path / "fleet.key").read_text()) == hashlib.sha256(b"fleet-passphrase-1").digest()


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_square_frames(tmp_path_factory.mktemp("signing_frames"), 20, (100, 50))


class SigningRig:
    """A daemon (process) with signing on and unsigned packets refused, behind the autopilot peer; its key
    from keygen; the status query over Zenoh."""

    def __init__(self, tmp_path: Path, frames_dir: Path, peers: tuple[AutopilotPeer, int, int]) -> None:
        import hashlib

        _, service_port, self.gcs_port = peers
        made = keygen(tmp_path / "mavlink.key")
        assert made.returncode == 0, made.stderr
        self.passphrase = made.stdout.split("signing key): ")[1].strip()
        self.key = hashlib.sha256(self.passphrase.encode("ascii")).digest()
        zenoh_port = free_tcp_port()
        self.daemon = Daemon(tmp_path, daemon_config(
            service_port, zenoh_port, {"kind": "file", "path": str(frames_dir), "loop": True},
            {"signing": {"key_file": str(tmp_path / "mavlink.key")}}))
        self.session = zenoh_session(zenoh_port)
        self.stations: list[GroundStation] = []

    def station(self, key: bytes | None) -> GroundStation:
        station = GroundStation(self.gcs_port, key=key).start()
        self.stations.append(station)
        return station

    def status(self) -> dict:
        return query_status(self.session)

    def wait_status(self, predicate, timeout_s: float = 10.0) -> dict:
        """The first status answer that satisfies predicate (asked again on each answer that does not)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            status = self.status()
            if predicate(status):
                return status
        raise AssertionError(f"status never satisfied the condition; last: {status}")

    def close(self) -> str:
        for station in self.stations:
            station.close()
        self.session.close()
        return self.daemon.stop()


def refused(status: dict, message: str = "COMMAND_LONG") -> int:
    return status["mavlink_signing"]["refused_by_message"].get(message, 0)


def test_signing_accepts_signed_commands_and_refuses_unsigned_wrong_key_and_replayed_ones(
        tmp_path: Path, frames_dir: Path, peers: tuple[AutopilotPeer, int, int]) -> None:
    rig = SigningRig(tmp_path, frames_dir, peers)
    try:
        signed = rig.station(rig.key)
        assert camera_heartbeat(signed, 60.0), "no camera heartbeat"
        status = rig.wait_status(lambda s: s["source"]["state"] == "ok")
        assert status["mavlink_signing"]["enabled"] and not status["mavlink_signing"]["allow_unsigned"]
        # the camera signs what it sends: its heartbeats carry a signature (incompat flag 0x01)
        beat = [r.msg for r in signed.received.of("HEARTBEAT") if r.msg.get_srcComponent() == 100][-1]
        assert beat.get_msgbuf()[2] & 0x01 and signed.conn.mav.signing.goodsig_count > 0

        unsigned = rig.station(None)
        before = rig.status()
        unsigned.command_long(TRACK_RECT, [0.55, 0.3, 0.8, 0.6, 0, 0, 0], target=CAM)
        after = rig.wait_status(lambda s: refused(s) > refused(before))
        assert after["track"]["state"] == "idle"  # changed nothing ...
        assert after["counters"]["mavlink_commands"] == before["counters"]["mavlink_commands"]  # ... not even answered
        assert after["counters"]["mavlink_signing_refused_unsigned"] > before["counters"]["mavlink_signing_refused_unsigned"]
        assert unsigned.ack_count(TRACK_RECT) == 0

        wrong = rig.station(bytes(32))
        # posing as the signed station's stream (link id, system, component) with a timestamp hours ahead:
        # refused, and it must not move that stream's timestamp (the real station's next packets still pass)
        with wrong._send_lock:
            wrong.conn.mav.signing.link_id = signed.conn.mav.signing.link_id
            wrong.conn.mav.signing.timestamp = signed.conn.mav.signing.timestamp + 10 ** 9
        before = rig.status()
        wrong.command_long(TRACK_RECT, [0.55, 0.3, 0.8, 0.6, 0, 0, 0], target=CAM)
        after = rig.wait_status(lambda s: refused(s) > refused(before))
        assert after["counters"]["mavlink_signing_refused_bad_signature"] > \
            before["counters"]["mavlink_signing_refused_bad_signature"]
        assert after["track"]["state"] == "idle" and wrong.ack_count(TRACK_RECT) == 0

        track = signed.conn.mav.command_long_encode(*CAM, TRACK_RECT, 0, 0.55, 0.3, 0.8, 0.6, 0, 0, 0)
        signed.send(track)  # packed and signed now: its bytes are what an eavesdropper could record
        ack = signed.wait_ack(TRACK_RECT, 0)
        assert ack is not None and ack.result == ACCEPTED, ack
        rig.wait_status(lambda s: s["track"]["state"] != "idle")
        signed.command_long(STOP, [0, 0, 0, 0, 0, 0, 0], target=CAM)
        assert signed.wait_ack(STOP, 0).result == ACCEPTED
        before = rig.wait_status(lambda s: s["track"]["state"] == "idle")
        with signed._send_lock:
            signed.conn.write(track.get_msgbuf())  # the recorded packet again: signature valid, timestamp old
        # Waited on the command's own refusal: the wrong-key station's heartbeats raise the bad-signature count too,
        # and one of them could satisfy a wait on that count before the replay is read.
        after = rig.wait_status(lambda s: refused(s) > refused(before))
        assert after["counters"]["mavlink_signing_refused_bad_signature"] > \
            before["counters"]["mavlink_signing_refused_bad_signature"]
        assert after["counters"]["mavlink_signing_refused_unsigned"] == before["counters"]["mavlink_signing_refused_unsigned"]
        assert after["track"]["state"] == "idle"
        assert after["counters"]["mavlink_commands"] == before["counters"]["mavlink_commands"]
        assert signed.ack_count(TRACK_RECT) == 1
    finally:
        log = rig.close()
    assert "Traceback" not in log and "event=signing_enabled allow_unsigned=False" in log


MAVPROXY = Path(os.environ.get("JSAR_MAVPROXY", REPO / ".venv-mavproxy" / "bin" / "mavproxy.py"))


class MavProxy:
    """MAVProxy (its own environment, `make mavproxy`) as a ground station on the autopilot peer's ground port,
    commanding the camera (target system AP_SYSID, component 100); commands piped to its standard input."""

    def __init__(self, gcs_port: int, workdir: Path, master: str | None = None,
                 target: tuple[int, int] = CAM) -> None:
        """master: its link (default udpout to gcs_port); target: (system, component) its commands go to."""
        self.proc = subprocess.Popen(
            [str(MAVPROXY), f"--master={master or f'udpout:127.0.0.1:{gcs_port}'}", "--mav20", "--nowait",
             f"--target-system={target[0]}", f"--target-component={target[1]}", "--source-system=254",
             "--default-modules=signing,cmdlong,misc", f"--state-basedir={workdir}"],
            cwd=workdir, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, "MAVLINK20": "1", "HOME": str(workdir)})
        self._printed: list[str] = []
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:  # drained to the end, so the pipe never fills
            with self._changed:
                self._printed.append(line)
                self._changed.notify_all()

    def output(self) -> str:
        with self._changed:
            return "".join(self._printed)

    def wait_printed(self, text: str, timeout_s: float) -> bool:
        """Whether MAVProxy printed `text` within timeout_s."""
        with self._changed:
            return self._changed.wait_for(lambda: text in "".join(self._printed), timeout=timeout_s)

    def command(self, line: str) -> None:
        assert self.proc.poll() is None, "MAVProxy exited"
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def close(self) -> str:
        """Stop it (end of input, then SIGTERM) and return what it printed."""
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except (subprocess.TimeoutExpired, BrokenPipeError, OSError):
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=5)
        return self.output()


@pytest.mark.skipif(not MAVPROXY.exists(), reason=f"MAVProxy is not installed at {MAVPROXY} "
                    "(`make mavproxy` installs mavproxy==1.8.75 in .venv-mavproxy; JSAR_MAVPROXY names another)")
def test_mavproxy_signing_key_from_the_keygen_passphrase_commands_the_camera(
        tmp_path: Path, frames_dir: Path, peers: tuple[AutopilotPeer, int, int]) -> None:
    """MAVProxy's own signing: unsigned, its command changes nothing; after `signing key PASSPHRASE` (the
    passphrase keygen printed) the same command is accepted; `signing setup OTHER` (SETUP_SIGNING to the
    camera) does not change the camera's key: MAVProxy, now on OTHER, is refused."""
    rig = SigningRig(tmp_path, frames_dir, peers)
    workdir = tmp_path / "mavproxy"
    workdir.mkdir()
    mavproxy = MavProxy(rig.gcs_port, workdir)
    output = ""
    try:
        rig.wait_status(lambda s: s["source"]["state"] == "ok", 60.0)
        select = "long MAV_CMD_CAMERA_TRACK_RECTANGLE 0.55 0.3 0.8 0.6"
        before = rig.status()
        mavproxy.command(select)
        after = rig.wait_status(lambda s: refused(s) > refused(before), 30.0)
        assert after["track"]["state"] == "idle"
        assert after["counters"]["mavlink_commands"] == before["counters"]["mavlink_commands"]

        mavproxy.command(f"signing key {rig.passphrase}")
        mavproxy.command(select)
        after = rig.wait_status(lambda s: s["track"]["state"] != "idle", 30.0)
        assert after["counters"]["mavlink_accepted"] == before["counters"]["mavlink_accepted"] + 1

        before = rig.status()
        mavproxy.command("signing setup another-passphrase")  # SETUP_SIGNING to the camera, then its own key
        mavproxy.command("long MAV_CMD_CAMERA_STOP_TRACKING")
        after = rig.wait_status(lambda s: s["counters"]["mavlink_signing_refused_bad_signature"] >
                                before["counters"]["mavlink_signing_refused_bad_signature"], 30.0)
        assert after["track"]["state"] != "idle" and after["counters"]["mavlink_commands"] == \
            before["counters"]["mavlink_commands"]
        assert refused(after, "SETUP_SIGNING") == 0  # it came signed with the old key: passed, and ignored
    finally:
        output = mavproxy.close()
        log = rig.close()
    assert "Got COMMAND_ACK: CAMERA_TRACK_RECTANGLE: ACCEPTED" in output and "Sent secret_key" in output, output[-3000:]
    assert "Traceback" not in log


def test_the_web_stations_mavlink_side_signs_with_the_keygen_key(
        tmp_path: Path, frames_dir: Path, peers: tuple[AutopilotPeer, int, int]) -> None:
    """gcs.mavlink_station (jsar-gcs-web --signing-key FILE) with the daemon's key file: its selection is
    accepted; the same station without the key is not answered (NO_ACK after its retries)."""
    from gcs.mavlink_station import MavlinkStation, read_signing_key

    rig = SigningRig(tmp_path, frames_dir, peers)
    url = f"udpout:127.0.0.1:{rig.gcs_port}"
    signed = MavlinkStation([url], signing_key=read_signing_key(str(tmp_path / "mavlink.key")), ack_timeout_s=1.0)
    unsigned = MavlinkStation([url], system_id=254, ack_timeout_s=0.5, attempts=2)
    try:
        rig.wait_status(lambda s: s["source"]["state"] == "ok", 60.0)
        refused_outcome = unsigned.track_rectangle(AP_SYSID, 100, 0.55, 0.3, 0.8, 0.6)
        assert refused_outcome.result_name == "NO_ACK" and refused_outcome.attempts == 2
        outcome = signed.track_rectangle(AP_SYSID, 100, 0.55, 0.3, 0.8, 0.6)
        assert outcome.result_name == "ACCEPTED", outcome
        status = rig.wait_status(lambda s: s["track"]["state"] != "idle")
        assert refused(status) >= 2  # the unsigned station's two attempts
    finally:
        signed.close()
        unsigned.close()
        log = rig.close()
    assert "Traceback" not in log


@pytest.mark.skipif(not MAVPROXY.exists(), reason=f"MAVProxy is not installed at {MAVPROXY} (`make mavproxy`)")
@pytest.mark.firmware("arducopter")
def test_one_passphrase_signs_arducopter_the_camera_and_mavproxy(tmp_path: Path) -> None:
    """The deployment's key workflow on the real firmware (ArduCopter SITL, tests' ../shared/sitl): keygen's
    passphrase goes to ArduPilot by MAVProxy's `signing setup` (SETUP_SIGNING on SERIAL0, the link it never
    requires signing on), keygen's key file to the camera on SERIAL1. Before: the camera refuses the
    autopilot's unsigned heartbeats. After (and a reboot of the autopilot): it hears the autopilot, and
    MAVProxy's signed TRACK_RECTANGLE to the camera, routed by ArduPilot from SERIAL0 to SERIAL1 with its
    signature, is accepted."""
    from sim.firmware import ArduPilotSitl

    frames = tmp_path / "frames"
    frames.mkdir()
    write_square_frames(frames, 20, (100, 50))
    made = keygen(tmp_path / "mavlink.key")
    assert made.returncode == 0, made.stderr
    passphrase = made.stdout.split("signing key): ")[1].strip()
    zenoh_port = free_tcp_port()
    with ArduPilotSitl(links=2) as firmware:
        firmware.start()
        config = daemon_config(0, zenoh_port, {"kind": "file", "path": str(frames), "loop": True},
                               {"signing": {"key_file": str(tmp_path / "mavlink.key")}})
        config["mavlink"].update({"url": firmware.companion_url, "system_id": 0})  # learned once heard
        daemon = Daemon(tmp_path, config)
        session = zenoh_session(zenoh_port)
        workdir = tmp_path / "mavproxy"
        workdir.mkdir()
        mavproxy = MavProxy(0, workdir, master=firmware.gcs_url, target=firmware.target)
        output = ""
        try:
            def status_when(predicate, timeout_s: float) -> dict:
                deadline = time.monotonic() + timeout_s
                while time.monotonic() < deadline:
                    status = query_status(session)
                    if predicate(status):
                        return status
                raise AssertionError(f"status never satisfied the condition; last: {status}")
            before = status_when(lambda s: refused(s, "HEARTBEAT") > 0, 60.0)  # the autopilot, unsigned
            assert before["autopilot"]["state"] == "waiting_for_heartbeat"
            # MAVProxy listens (udpin): it can send only once it has heard the autopilot
            assert mavproxy.wait_printed(f"Detected vehicle {firmware.system_id}:1", 30.0), mavproxy.output()[-3000:]
            mavproxy.command(f"signing setup {passphrase}")
            # ArduPilot checks the key on SERIAL1 at once but signs what it sends there only after a reboot
            # (measured on this firmware: its heartbeats stayed unsigned for 30 s, then signed after `reboot`)
            mavproxy.command("reboot")
            heard = status_when(lambda s: s["autopilot"]["state"] == "connected", 60.0)
            assert heard["mavlink_system_id"] == firmware.system_id
            status_when(lambda s: s["source"]["state"] == "ok", 30.0)
            mavproxy.command("set target_component 100")
            tracking = None
            for _ in range(5):  # as an operator would: MAVProxy may still send to the autopilot's old address
                mavproxy.command("long MAV_CMD_CAMERA_TRACK_RECTANGLE 0.55 0.3 0.8 0.6")
                with contextlib.suppress(AssertionError):
                    tracking = status_when(lambda s: s["track"]["state"] != "idle", 6.0)
                    break
            assert tracking is not None, f"never tracking; MAVProxy printed:\n{mavproxy.output()[-4000:]}"
            assert tracking["counters"]["mavlink_accepted"] >= 1
        finally:
            output = mavproxy.close()
            session.close()
            log = daemon.stop()
    assert "Sent secret_key" in output and "Got COMMAND_ACK: CAMERA_TRACK_RECTANGLE: ACCEPTED" in output, output[-3000:]
    assert "Traceback" not in log
