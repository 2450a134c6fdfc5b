"""The daemon as a process: systemd notify + watchdog, the MAVLink handshake with a ground station through
an autopilot peer, Zenoh status / telemetry, SIGTERM / SIGINT stop within 2 s; the systemd unit passes `systemd-analyze verify`."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest
import yaml

from sim.ports import free_tcp_port, free_udp_port, free_udp_ports
from tests.helpers import write_square_frames
from tests.service_peers import AutopilotPeer, GroundStation, camera_handshake

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "deploy" / "jsar-service.service"


def test_systemd_unit_verifies(tmp_path: Path) -> None:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed: cannot verify the unit here")
    text = UNIT.read_text()
    for required in ("Type=notify", "WatchdogSec=", "Restart=on-failure", "DeviceAllow=char-video4linux rw",
                     "NoNewPrivileges=yes", "ProtectSystem=strict", "User=jsar"):
        assert required in text, required
    # verify needs an existing ExecStart binary: point it at this checkout's console script
    script = Path(sys.executable).with_name("jsar-service")
    if not script.exists():
        pytest.skip(f"console script {script} is not installed (pip install -e .)")
    unit = tmp_path / "jsar-service.service"
    unit.write_text(text.replace("/opt/jsar/.venv/bin/jsar-service", str(script))
                        .replace("WorkingDirectory=/opt/jsar", f"WorkingDirectory={tmp_path}"))
    proc = subprocess.run([tool, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    problems = [line for line in (proc.stdout + proc.stderr).splitlines() if unit.name in line]
    assert proc.returncode == 0 and not problems, proc.stdout + proc.stderr


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_square_frames(tmp_path_factory.mktemp("daemon_frames"), 20, (100, 50))


def _recv_until(sock: socket.socket, wanted: str, timeout_s: float) -> list[str]:
    """Notify datagrams until one contains `wanted` (socket timeout bounds the wait)."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            seen.append(sock.recv(4096).decode())
        except socket.timeout:
            break
        if wanted in seen[-1]:
            return seen
    raise AssertionError(f"no {wanted!r} notification within {timeout_s} s; got {seen}")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_daemon_notifies_systemd_serves_status_and_stops_within_2s(tmp_path: Path, frames_dir: Path, signum: int) -> None:
    import zenoh

    zenoh_port = free_tcp_port()
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    config["tracker"]["name"] = "csrt"
    config["tracker"]["range_size_band"] = 0  # csrt has no side bounds
    config["zenoh"].update({"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "daemontest"})
    config["source"].update({"loop": True})
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(config))
    notify_path = tmp_path / "notify.sock"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(notify_path))
    env = {**os.environ, "NOTIFY_SOCKET": str(notify_path), "WATCHDOG_USEC": "400000", "MAVLINK20": "1"}
    env.pop("WATCHDOG_PID", None)
    service_port, gcs_port = free_udp_ports(2)
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=7).start()
    gcs = GroundStation(gcs_port).start()
    proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(config_file), "--source", str(frames_dir),
                             "--mavlink", f"udpout:127.0.0.1:{service_port}"],
                            cwd=REPO, env=env, stderr=subprocess.PIPE, text=True)
    session = None
    try:
        _recv_until(notify, "READY=1", 60.0)
        _recv_until(notify, "WATCHDOG=1", 5.0)
        info = camera_handshake(gcs, system_id=7, timeout_s=10.0)
        assert (info.resolution_h, info.resolution_v) == (160, 120)
        zc = zenoh.Config()
        zc.insert_json5("mode", '"peer"')
        zc.insert_json5("scouting/multicast/enabled", "false")
        zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
        session = zenoh.open(zc)
        status = None
        for _ in range(50):  # until the connection is up and the queryable answers
            replies = list(session.get("daemontest/status", timeout=1.0))
            if replies and replies[0].ok is not None:
                status = json.loads(replies[0].ok.payload.to_string())
                if status["source"]["frames"] > 0:
                    break
        assert status is not None and status["status"] == "ok"
        # the autopilot peer's heartbeat arrived (the handshake came through it); waiting before it: test_service_mavlink
        assert status["autopilot"]["state"] == "connected" and status["autopilot"]["alive"] is True
        assert status["config"]["zenoh"]["prefix"] == "daemontest" and status["config"]["source"]["kind"] == "file"
        sent = time.monotonic()
        proc.send_signal(signum)
        try:
            code = proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            tail = (proc.stderr.read() if proc.stderr else "")[-3000:]
            pytest.fail(f"daemon still running 10 s after {signal.Signals(signum).name}; its log:\n{tail}")
        elapsed = time.monotonic() - sent
        assert code == 0
        assert elapsed < 2.0, f"stopped after {elapsed:.2f} s"
        assert any("STOPPING=1" in m for m in _recv_until(notify, "STOPPING=1", 1.0))
    finally:
        if session is not None:
            session.close()
        gcs.close()
        autopilot.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        notify.close()
    stderr = proc.stderr.read() if proc.stderr else ""
    assert "event=started" in stderr and "event=stopped" in stderr and "Traceback" not in stderr
    assert stderr.count("waiting for the autopilot's heartbeat") == 1, stderr


# The daemon with the name resolver and UDP connect faked (tests stay on loopback): the resolver knows
# no.such.host.invalid as unknown, and 10.255.255.1 has no route.
FAKE_NETWORK = """
import errno, socket, sys
real_getaddrinfo, real_connect = socket.getaddrinfo, socket.socket.connect
def getaddrinfo(host, *args, **kwargs):
    if host == "no.such.host.invalid":
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
    return real_getaddrinfo(host, *args, **kwargs)
def connect(self, address):
    if address[0] == "10.255.255.1":
        raise OSError(errno.ENETUNREACH, "Network is unreachable")
    return real_connect(self, address)
socket.getaddrinfo, socket.socket.connect = getaddrinfo, connect
from service.__main__ import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("url, error", [
    ("udpout:no.such.host.invalid:14550",
     "mavlink.url: cannot resolve host 'no.such.host.invalid' of udpout:no.such.host.invalid:14550: Name or service not known"),
    ("udpout:10.255.255.1:14550", "mavlink.url: udpout:10.255.255.1:14550 is unreachable: Network is unreachable"),
    ("udpin:no.such.host.invalid:14550", "mavlink.url: cannot resolve host 'no.such.host.invalid'"),
])
def test_unresolvable_or_unreachable_link_stops_the_daemon_at_start(tmp_path: Path, frames_dir: Path, url: str,
                                                                    error: str) -> None:
    """pymavlink's udpout opens whatever the host; without the start-up check every message was lost
    in silence while the daemon tracked on."""
    config = {"tracker": {"name": "csrt", "range_size_band": 0}, "zenoh": {"enabled": False}}
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(config))
    proc = subprocess.run([sys.executable, "-c", FAKE_NETWORK, "--config", str(config_file), "--source", str(frames_dir),
                           "--mavlink", url], cwd=REPO, env={**os.environ, "MAVLINK20": "1"}, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    assert "event=startup_failed" in proc.stderr and error in proc.stderr, proc.stderr
    assert "event=started" not in proc.stderr


def test_stop_is_prompt_even_while_the_tracker_is_stuck_in_a_frame(frames_dir: Path) -> None:
    import threading

    from service.app import Service
    from tests.service_peers import RunningService, service_config

    entered, release = threading.Event(), threading.Event()

    class StuckTracker:
        def init(self, image, box) -> None:
            pass

        def update(self, image):
            entered.set()
            release.wait(30.0)  # a pathological frame (e.g. a very slow re-detection)
            raise RuntimeError("released")

    config = service_config(free_udp_port(), {"source": {"path": str(frames_dir), "loop": True}})
    service = Service(config)
    service.loop.make_tracker = StuckTracker
    running = RunningService(service).start()
    try:
        assert service.worker.health.wait_for(lambda h: h.state == "ok", 10.0)
        from service.mavlink.commands import TrackRectangle
        service.selections.put(TrackRectangle(0.5, 0.3, 0.7, 0.6))
        assert entered.wait(10.0)
        started = time.monotonic()
        running.stop_event.set()
        running.thread.join(5.0)
        assert not running.thread.is_alive() and time.monotonic() - started < 2.0
    finally:
        release.set()


def test_jsar_re_s_verifier_network_loads_at_start_not_on_the_first_selection(frames_dir: Path, caplog) -> None:
    """About 1 s of loading would otherwise hold the loop on the operator's first selection (frames queue, the
    gimbal waits); jsar and csrt have no model to load (and jsar's own `prepare(frame)` is not called)."""
    import logging

    from service.app import Service
    from tests.service_peers import service_config

    caplog.set_level(logging.INFO, logger="service")
    for name, band, prepared in (("jsar-re", 2, True), ("jsar", 2, False), ("csrt", 0, False)):
        config = service_config(free_udp_port(), {"source": {"path": str(frames_dir)},
                                                  "tracker": {"name": name, "range_size_band": band}})
        service = Service(config)
        try:
            lines = [r.getMessage() for r in caplog.records if "event=tracker_prepared" in r.getMessage()]
            assert bool([line for line in lines if f"tracker={name} " in line]) is prepared, lines
        finally:
            service.link.close()  # built, never run: no thread to stop
    from jsar.redetect.appearance import shared_embedder
    assert shared_embedder.cache_info().currsize == 1  # the network every later JsarReTracker shares


def test_jsar_re_s_deferred_verifier_work_gets_a_thread_named_for_the_os(frames_dir: Path, caplog,
                                                                          monkeypatch) -> None:
    """tracker.verifier_thread: each new jsar-re runs its deferred embeddings on one executor whose thread the OS
    knows as "verifier" (bench.service's per-thread report); off, or for a tracker without deferred work, there is
    none, and the log says which at start."""
    from service.config import TrackerConfig

    assert TrackerConfig().verifier_thread == "auto"
    import logging
    import threading

    from service.app import Service
    from tests.service_peers import service_config

    from service import app as service_app

    caplog.set_level(logging.INFO, logger="service")
    # "auto" counts the CPUs the service may run on (its affinity mask): four give the thread, two do not.
    for name, band, thread, cpus in (("jsar-re", 2, True, 2), ("jsar-re", 2, False, 8), ("jsar", 2, True, 8),
                                     ("jsar-re", 2, "auto", 4), ("jsar-re", 2, "auto", 2)):
        config = service_config(free_udp_port(), {"source": {"path": str(frames_dir)},
                                                  "tracker": {"name": name, "range_size_band": band,
                                                              "verifier_thread": thread}})
        monkeypatch.setattr(service_app.os, "sched_getaffinity", lambda pid, cpus=cpus: set(range(cpus)))
        service = Service(config)
        try:
            expected = (thread is True or (thread == "auto" and cpus >= 4)) and name == "jsar-re"
            assert f"setting={str(thread).lower()} cpus={cpus}" in caplog.text
            assert (service.verifier_worker is not None) is expected
            assert f"event=verifier_thread tracker={name} enabled={str(expected).lower()}" in caplog.text
            tracker = service._new_tracker()
            if expected:
                assert tracker.worker is service.verifier_worker
                os_name = service.verifier_worker.submit(
                    lambda: Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip())
                assert os_name.result(timeout=10) == "verifier"
        finally:
            service.link.close()  # built, never run
            if service.verifier_worker is not None:
                service.verifier_worker.shutdown(wait=True)
        caplog.clear()


class _StderrLines:
    """The daemon's stderr read line by line on a thread; wait_for(text) waits on a condition, not a sleep."""

    def __init__(self, proc: subprocess.Popen) -> None:
        import threading

        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen) -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            with self._cond:
                self.lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self.lines.append("")  # end of output: the daemon has exited
            self._cond.notify_all()

    def count(self, text: str) -> int:
        with self._cond:
            return sum(text in line for line in self.lines)

    def wait_for(self, text: str, times: int, timeout_s: float) -> None:
        with self._cond:
            self._cond.wait_for(lambda: sum(text in line for line in self.lines) >= times or "" in self.lines,
                                timeout=timeout_s)
            if sum(text in line for line in self.lines) < times:
                raise AssertionError(f"{text!r} not logged {times} times within {timeout_s} s:\n" + "".join(self.lines))

    def text(self, timeout_s: float) -> str:
        self._thread.join(timeout_s)
        with self._cond:
            return "".join(self.lines)


def _stop_daemon(proc: subprocess.Popen) -> int:
    """SIGTERM and the exit code (killed after 10 s)."""
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def test_daemon_takes_the_url_form_of_a_mavlink_link(tmp_path: Path, frames_dir: Path) -> None:
    """`--mavlink udpout://HOST:PORT`, the form `jsar-gcs --url` (mavsdk) takes, once stopped the daemon at
    start ("cannot resolve host '//127.0.0.1'"); now it is pymavlink's udpout:HOST:PORT and the camera meets a
    ground station through the autopilot on it."""
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump({"tracker": {"name": "csrt", "range_size_band": 0},
                                           "zenoh": {"enabled": False},
                                           "source": {"loop": True}}))
    service_port, gcs_port = free_udp_ports(2)
    autopilot = AutopilotPeer(service_port, gcs_port, system_id=7).start()
    gcs = GroundStation(gcs_port).start()
    proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(config_file), "--source", str(frames_dir),
                             "--mavlink", f"udpout://127.0.0.1:{service_port}"],
                            cwd=REPO, env={**os.environ, "MAVLINK20": "1"}, stderr=subprocess.PIPE, text=True)
    log = _StderrLines(proc)
    try:
        log.wait_for("event=started", 1, 60.0)
        camera_handshake(gcs, system_id=7, timeout_s=10.0)
        assert _stop_daemon(proc) == 0
    finally:
        gcs.close()
        autopilot.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = log.text(5.0)
    assert f"mavlink=udpout:127.0.0.1:{service_port} " in stderr, stderr
    assert "//" not in stderr and "Traceback" not in stderr, stderr


def test_an_absent_camera_is_retried_not_a_configuration_error(tmp_path: Path) -> None:
    """Unlike a missing file (source.path, exit 2: test_service_config), a /dev/video* device absent at start
    may be plugged in later: the daemon starts, reports the source fault and retries it with backoff."""
    device = "/dev/video97"
    if os.path.exists(device):
        pytest.skip(f"{device} exists on this machine")
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump({"tracker": {"name": "csrt", "range_size_band": 0},
                                           "zenoh": {"enabled": False},
                                           "source": {"retry_initial_s": 0.1, "retry_max_s": 0.4}}))
    autopilot = AutopilotPeer(*free_udp_ports(2)).start()
    proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(config_file), "--source", device,
                             "--mavlink", f"udpout:127.0.0.1:{autopilot.links['service'].sock.getsockname()[1]}"],
                            cwd=REPO, env={**os.environ, "MAVLINK20": "1"}, stderr=subprocess.PIPE, text=True)
    log = _StderrLines(proc)
    try:
        log.wait_for("event=started", 1, 60.0)
        for delay_s in ("0.1", "0.2", "0.4"):  # the backoff doubles (a source state is logged when it changes)
            log.wait_for(f"camera {device} is absent (unplugged?); retry in {delay_s} s", 1, 10.0)
        assert proc.poll() is None, "the daemon stopped on an absent camera"
        assert _stop_daemon(proc) == 0
    finally:
        autopilot.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = log.text(5.0)
    assert "configuration error" not in stderr and "Traceback" not in stderr, stderr


def test_a_v4l2_device_absent_at_start_or_unplugged_mid_run_is_retried(tmp_path: Path, monkeypatch) -> None:
    """The service builds with its camera absent (no ConfigError), retries it, tracks frames once it is
    plugged in, and after an unplug mid-run retries again until it is back. The device node is a file in
    tmp_path and OpenCV's V4L2 capture a fake that delivers frames while that file exists."""
    import threading

    import numpy as np

    from service.app import Service
    from service.config import config_from_mapping
    from service.sources import v4l2

    device = tmp_path / "video0"

    class FakeCapture:
        """cv2.VideoCapture on a V4L2 device: frames while the device node exists."""

        def __init__(self, path: str, api: int) -> None:
            assert (path, api) == (str(device), cv2.CAP_V4L2)
            self.frame_period = threading.Event()

        def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
            return device.exists()

        def set(self, prop: int, value: float) -> bool:
            return True

        def read(self) -> tuple[bool, np.ndarray | None]:
            self.frame_period.wait(0.01)  # a camera's frame interval (pacing, not synchronisation)
            if not device.exists():
                return False, None
            return True, np.zeros((48, 64, 3), np.uint8)

        def release(self) -> None:
            pass

    monkeypatch.setattr(v4l2.cv2, "VideoCapture", FakeCapture)
    config = config_from_mapping({
        "source": {"kind": "v4l2", "device": str(device), "retry_initial_s": 0.01, "retry_max_s": 0.05},
        "tracker": {"name": "csrt", "range_size_band": 0}, "zenoh": {"enabled": False},
        "mavlink": {"url": f"udpout:127.0.0.1:{free_udp_port()}"}})
    service = Service(config)  # an absent camera is not a configuration error
    health = service.worker.health
    service.worker.start()
    try:
        assert health.wait_for(lambda h: h.failures >= 2 and h.state == "error", 5.0)
        assert "is absent (unplugged?); retry in" in health.reason
        device.touch()  # plugged in
        assert health.wait_for(lambda h: h.state == "ok" and h.frames >= 3, 5.0)
        failures = health.failures
        device.unlink()  # unplugged mid-run
        assert health.wait_for(lambda h: h.failures >= failures + 2 and "is absent" in h.reason, 5.0)
        frames = health.frames
        device.touch()  # back
        assert health.wait_for(lambda h: h.state == "ok" and h.frames > frames, 5.0)
    finally:
        service.worker.stop()
        service.link.close()
