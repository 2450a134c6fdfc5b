"""Zenoh mutual TLS and access control (issue 42), on loopback, with the daemon as a process.

The certificates are made at test time by docs/security.md's own openssl recipe (run as written, in a
temporary folder): one CA with a drone, a station (`gcs`) and a read-only `viewer`; a second, unrelated
CA with its own `gcs` certificate (a stranger who copied the station's name). The daemon listens on
`tls/127.0.0.1` (mTLS, the drone's certificate, an access list by certificate common name) and, for the
local camera, on `tcp/127.0.0.1` (subject: loopback interface and tcp only). Multicast scouting is off.
"""
from __future__ import annotations

import json
import logging
import re
import shutil
import subprocess
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
import zenoh

from gcs.drones import DroneDirectory, ZenohSettings
from gcs.router import router_config
from gcs.zenoh_tls import ZenohTls
from service.config import ConfigError, ZenohConfig, ZenohTlsConfig, config_from_mapping
from service.sources.zenoh_wire import encode_frame
from service.telemetry import access_control_section, insecure_endpoints, open_session, zenoh_config
from sim.daemon import Daemon
from sim.ports import free_tcp_port, free_udp_port, free_tcp_ports
from sim.zenoh_link import SimCamera, ZenohEndpoints
from sim.web_station import WebStation
from tests.helpers import LocalCamera
from tests.zenoh_router import Router

ROOT = Path(__file__).resolve().parent.parent
PREFIX = "jsar"
INTRUDER_SIZE = (96, 64)  # of the frames a read-only peer tries to publish (the local camera's: 160x120)
START_TIMEOUT_S = 60.0  # the daemon's start (imports, Zenoh) on a loaded 2-core machine

needs_openssl = pytest.mark.skipif(shutil.which("openssl") is None or shutil.which("sh") is None,
                                   reason="openssl (and sh) are needed to make the test certificates")


def recipe() -> str:
    """The shell block docs/security.md marks `recipe: zenoh-pki`."""
    text = (ROOT / "docs" / "security.md").read_text(encoding="utf-8")
    match = re.search(r"<!-- recipe: zenoh-pki[^>]*-->\s*```sh\n(.*?)```", text, re.S)
    assert match, "docs/security.md lost its zenoh-pki recipe block"
    return match.group(1)


def make_pki(folder: Path, extra: str = "") -> Path:
    """Run the documented recipe (plus `extra` shell lines, in the same shell) in `folder`; its pki/ folder."""
    folder.mkdir(parents=True, exist_ok=True)
    run = subprocess.run(["sh", "-ec", recipe() + extra], cwd=folder, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, f"the docs recipe failed:\n{run.stdout}\n{run.stderr}"
    return folder / "pki"


def documented_zenoh() -> dict[str, Any]:
    """The `zenoh:` section of docs/security.md's drone config block (marked `config: zenoh-security`)."""
    text = (ROOT / "docs" / "security.md").read_text(encoding="utf-8")
    match = re.search(r"<!-- config: zenoh-security[^>]*-->\s*```yaml\n(.*?)```", text, re.S)
    assert match, "docs/security.md lost its zenoh-security config block"
    return yaml.safe_load(match.group(1))["zenoh"]


def access_list() -> dict[str, Any]:
    """The documented access list: the station reads and queries status, the viewer only reads, loopback tcp
    (the local camera) may do anything."""
    access = documented_zenoh()["access"]
    assert PREFIX == "jsar" and "jsar/track" in access["rules"][0]["key_exprs"]
    return access


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two CAs made by the docs' recipe: `ours` (drone-1, gcs, viewer) and `other` (its own gcs)."""
    if shutil.which("openssl") is None or shutil.which("sh") is None:
        pytest.skip("openssl (and sh) are needed to make the test certificates")
    base = tmp_path_factory.mktemp("pki")
    return {"ours": make_pki(base / "ours", 'cert viewer "DNS:viewer"\ncert router "DNS:router,IP:127.0.0.1"\n'),
            "other": make_pki(base / "other")}


@pytest.fixture(scope="module")
def drone(pki: dict[str, Path], tmp_path_factory: pytest.TempPathFactory):
    """The daemon (`--source zenoh`, TLS + access list) and its local camera; yields (daemon, camera, tls endpoint)."""
    ours = pki["ours"]
    tls_port, local_port = free_tcp_ports(2)
    tls_endpoint = f"tls/127.0.0.1:{tls_port}"
    overrides = {
        "source": {"kind": "zenoh"},
        "tracker": {"name": "csrt", "params": {}, "range_size_band": 0},
        "zenoh": {"enabled": True, "mode": "peer", "listen": [tls_endpoint, f"tcp/127.0.0.1:{local_port}"],
                  "connect": [], "multicast_scouting": False, "prefix": PREFIX,
                  # the documented tls section, its files where the recipe made them
                  "tls": {k: v.replace("/etc/jsar/zenoh", str(ours)) if isinstance(v, str) else v
                          for k, v in documented_zenoh()["tls"].items()},
                  "access": access_list()},
        "video": {"preview": {"enabled": True, "max_fps": 15.0}},
    }
    daemon = Daemon(tmp_path_factory.mktemp("daemon"), overrides, f"udpout:127.0.0.1:{free_udp_port()}").start()
    sim = SimCamera(ZenohEndpoints(connect=(f"tcp/127.0.0.1:{local_port}",), prefix=PREFIX))
    daemon.on_exit(sim.telemetry.mark_source_gone)
    camera = LocalCamera(sim)
    try:
        if sim.telemetry.wait_frame(1, START_TIMEOUT_S) is None:
            raise daemon.exited_error("at start") if not daemon.alive() else AssertionError(
                f"no telemetry from the daemon within {START_TIMEOUT_S} s; its log:\n{daemon.log_tail()}")
        yield daemon, camera, tls_endpoint
    finally:
        camera.close()
        sim.close()
        code = daemon.stop()
        assert code == 0, f"the daemon exited {code}; its log:\n{daemon.log_tail()}"


def station_settings(pki: dict[str, Path], endpoint: str) -> ZenohSettings:
    """The web station's Zenoh settings (what --zenoh ENDPOINT --zenoh-tls-ca/-cert/-key give)."""
    ours = pki["ours"]
    return ZenohSettings(connect=(endpoint,), tls=ZenohTls(str(ours / "ca.crt"), str(ours / "gcs.crt"),
                                                          str(ours / "gcs.key")))


def raw_config(endpoint: str, tls: dict[str, Any] | None = None) -> zenoh.Config:
    """A bare peer's zenoh.Config: one connect endpoint, no listening, no scouting, optional TLS keys."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    for key, value in (tls or {}).items():
        config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return config


class Listener:
    """A Zenoh session counting what it receives on `<prefix>/track` and `<prefix>/camera/preview`
    (subscribed to those exact keys)."""

    def __init__(self, config: zenoh.Config, prefix: str = PREFIX) -> None:
        self.session = zenoh.open(config)
        self.prefix = prefix
        self.counts = {"track": 0, "camera/preview": 0}
        self.cond = threading.Condition()
        self.subs = [self.session.declare_subscriber(f"{prefix}/{suffix}", self._counter(suffix))
                     for suffix in self.counts]

    def _counter(self, suffix: str):
        def count(_sample: zenoh.Sample) -> None:
            with self.cond:
                self.counts[suffix] += 1
                self.cond.notify_all()
        return count

    def wait(self, track: int, previews: int, timeout_s: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: self.counts["track"] >= track and
                                      self.counts["camera/preview"] >= previews, timeout=timeout_s)

    def status_answers(self, timeout_s: float = 2.0) -> int:
        return sum(1 for reply in self.session.get(f"{self.prefix}/status", timeout=timeout_s) if reply.ok is not None)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.session.close()


# ----- the refusal table ---------------------------------------------------------------------------------

@needs_openssl
def test_station_with_the_right_certificate_receives_telemetry_video_and_status(pki, drone) -> None:
    daemon, _camera, endpoint = drone
    directory = DroneDirectory(station_settings(pki, endpoint), status_every_s=0.5)
    try:
        directory.watch(PREFIX)

        def served() -> bool:
            d = directory.drones.get(PREFIX)
            return d is not None and d.last_track is not None and d.previews >= 3 and d.system_id is not None
        assert directory.wait_for(served, 20.0), f"station not served over mTLS; daemon log:\n{daemon.log_tail()}"
        summary = directory.summaries()[0]
        assert summary["prefix"] == PREFIX and summary["online"] and summary["daemon_status"] == "ok"
        assert summary["state"] == "idle"
    finally:
        directory.close()


@needs_openssl
@pytest.mark.parametrize("peer", ["plain-tcp", "tls-without-client-certificate", "certificate-from-another-ca"])
def test_peer_without_the_right_certificate_is_refused(pki, drone, peer: str) -> None:
    daemon, _camera, endpoint = drone
    ours, other = pki["ours"], pki["other"]
    config = {
        "plain-tcp": lambda: raw_config(endpoint.replace("tls/", "tcp/")),
        "tls-without-client-certificate": lambda: raw_config(endpoint, {"root_ca_certificate": str(ours / "ca.crt")}),
        # trusts the drone (our CA) but shows a certificate with the station's name made by another CA
        "certificate-from-another-ca": lambda: ZenohSettings(connect=(endpoint,), tls=ZenohTls(
            str(ours / "ca.crt"), str(other / "gcs.crt"), str(other / "gcs.key"))).to_zenoh(),
    }[peer]()
    intruder = Listener(config)
    # a station opened after the intruder is served at once: the intruder had as long to connect, and more
    station = Listener(station_settings(pki, endpoint).to_zenoh())
    try:
        assert station.wait(track=10, previews=3, timeout_s=20.0), "the right station was not served"
        assert station.status_answers() == 1
        assert list(intruder.session.info.peers_zid()) == [], f"{peer}: a session with the daemon was opened"
        assert intruder.counts == {"track": 0, "camera/preview": 0}, f"{peer}: received {intruder.counts}"
        assert intruder.status_answers(timeout_s=1.0) == 0
        assert daemon.alive()
    finally:
        intruder.close()
        station.close()


@needs_openssl
def test_read_only_viewer_cannot_publish_frames_or_query_status(pki, drone) -> None:
    daemon, camera, endpoint = drone
    ours = pki["ours"]
    viewer = Listener(ZenohSettings(connect=(endpoint,), tls=ZenohTls(
        str(ours / "ca.crt"), str(ours / "viewer.crt"), str(ours / "viewer.key"))).to_zenoh())
    station = Listener(station_settings(pki, endpoint).to_zenoh())
    log = camera.sim.telemetry
    intruder_image = np.full((INTRUDER_SIZE[1], INTRUDER_SIZE[0], 3), 200, np.uint8)
    try:
        assert viewer.wait(track=5, previews=3, timeout_s=20.0), "the viewer may read: it should get telemetry and video"
        # its frames, interleaved with the camera's for 1.5 s (ids from 1e6, another size) ...
        stop = threading.Event()
        publisher = viewer.session.declare_publisher(f"{PREFIX}/camera/frame")
        for i in range(30):
            publisher.put(encode_frame(intruder_image, 1_000_000 + i, 0.0))
            stop.wait(0.05)  # pacing the intruder like a camera, not synchronisation
        publisher.undeclare()
        # ... then the same burst from the local camera (ids from 2e6): these must be tracked, which shows
        # the burst would have been seen had the viewer's frames been let through
        for i in range(30):
            camera.sim.publish(intruder_image, 2_000_000 + i)
            stop.wait(0.05)
        with log.cond:
            assert log.cond.wait_for(lambda: any(f >= 2_000_000 for f in log.by_frame), timeout=10.0), \
                "the control burst was not tracked"
            seen = dict(log.by_frame)
        assert not [f for f in seen if 1_000_000 <= f < 2_000_000], "a frame the viewer published was tracked"
        controls = [s for f, s in seen.items() if f >= 2_000_000]
        assert all(s["image_size"] == list(INTRUDER_SIZE) for s in controls)
        assert viewer.status_answers() == 0, "the viewer's status query was answered"
        assert station.status_answers() == 1, "the station's status query was not answered (control)"
        assert daemon.alive()
    finally:
        viewer.close()
        station.close()


# ----- through a router: the same TLS settings on gcs.router and the web station ------------------------

ROUTER_ACCESS = {  # the router's own access list (gcs.router --access): the drone and the station, nobody else
    "enabled": True, "default_permission": "deny",
    "rules": [{"id": "all", "permission": "allow", "messages": ["put", "delete", "declare_subscriber", "query",
                                                                "declare_queryable",
                                         "reply"], "key_exprs": ["**"]}],
    "subjects": [{"id": "fleet", "cert_common_names": ["drone-1", "gcs"]}],
    "policies": [{"rules": ["all"], "subjects": ["fleet"]}],
}


@needs_openssl
def test_through_a_tls_router_the_station_is_served_and_others_are_refused(pki, tmp_path: Path) -> None:
    ours, other = pki["ours"], pki["other"]
    prefix = "via-router"
    router_endpoint, local_port = f"tls/127.0.0.1:{free_tcp_port()}", free_tcp_port()
    access_file = tmp_path / "router-access.yaml"
    access_file.write_text(yaml.safe_dump(ROUTER_ACCESS), encoding="utf-8")
    tls_args = ("--tls-ca", str(ours / "ca.crt"), "--tls-cert", str(ours / "router.crt"),
                "--tls-key", str(ours / "router.key"), "--access", str(access_file))
    router = Router(router_endpoint, tls_args).start()
    overrides = {
        "source": {"kind": "zenoh"},
        "tracker": {"name": "csrt", "params": {}, "range_size_band": 0},
        "zenoh": {"enabled": True, "mode": "peer", "listen": [f"tcp/127.0.0.1:{local_port}"],
                  "connect": [router_endpoint], "multicast_scouting": False, "prefix": prefix,
                  "tls": {"enabled": True, "root_ca_certificate": str(ours / "ca.crt"),
                          "certificate": str(ours / "drone-1.crt"), "private_key": str(ours / "drone-1.key")},
                  "access": {"enabled": False}},
    }
    (tmp_path / "daemon").mkdir()
    daemon = Daemon(tmp_path / "daemon", overrides, f"udpout:127.0.0.1:{free_udp_port()}").start()
    sim = SimCamera(ZenohEndpoints(connect=(f"tcp/127.0.0.1:{local_port}",), prefix=prefix))
    daemon.on_exit(sim.telemetry.mark_source_gone)
    camera = LocalCamera(sim)
    station = WebStation([f"udpin:127.0.0.1:{free_udp_port()}"], [router_endpoint], extra_args=(
        "--zenoh-mode", "client", "--zenoh-tls-ca", str(ours / "ca.crt"), "--zenoh-tls-cert", str(ours / "gcs.crt"),
        "--zenoh-tls-key", str(ours / "gcs.key")))
    strangers = {
        "plain-tcp": raw_config(router_endpoint.replace("tls/", "tcp/")),
        "certificate-from-another-ca": ZenohSettings(connect=(router_endpoint,), tls=ZenohTls(
            str(ours / "ca.crt"), str(other / "gcs.crt"), str(other / "gcs.key"))).to_zenoh(),
        # client mode: a peer would also learn the daemon's own (loopback) listen endpoint by gossip through the
        # router and connect to it directly, which on this one machine it can (docs/security.md)
        "viewer-not-in-the-router-access-list": ZenohSettings(connect=(router_endpoint,), mode="client", tls=ZenohTls(
            str(ours / "ca.crt"), str(ours / "viewer.crt"), str(ours / "viewer.key"))).to_zenoh(),
    }
    listeners: dict[str, Listener] = {}
    try:
        assert sim.telemetry.wait_frame(1, START_TIMEOUT_S) is not None, f"daemon silent:\n{daemon.log_tail()}"
        listeners = {name: Listener(config, prefix) for name, config in strangers.items()}
        station.start(START_TIMEOUT_S)  # after the strangers: they had longer to connect
        assert station.wait_line(f"event=drone_found prefix={prefix}", 20.0), station.output()
        assert station.wait_line("event=zenoh_connected", 5.0), station.output()
        # a second station certificate holder, counting what the router lets through to it
        fleet = Listener(ZenohSettings(connect=(router_endpoint,), tls=ZenohTls(
            str(ours / "ca.crt"), str(ours / "gcs.crt"), str(ours / "gcs.key"))).to_zenoh(), prefix)
        listeners["station-certificate"] = fleet
        assert fleet.wait(track=10, previews=3, timeout_s=20.0), "a station certificate was not served by the router"
        assert fleet.status_answers() == 1
        for name, listener in strangers_of(listeners).items():
            assert listener.counts == {"track": 0, "camera/preview": 0}, f"{name}: received {listener.counts}"
            assert listener.status_answers(timeout_s=1.0) == 0, f"{name}: status answered"
        assert list(listeners["plain-tcp"].session.info.peers_zid()) == []
        assert list(listeners["plain-tcp"].session.info.routers_zid()) == []
        assert list(listeners["certificate-from-another-ca"].session.info.routers_zid()) == []
        assert len(list(listeners["viewer-not-in-the-router-access-list"].session.info.routers_zid())) == 1, \
            "the viewer's certificate is valid: it connects, and the router's access list gives it nothing"
        assert daemon.alive() and station.alive()
    finally:
        for listener in listeners.values():
            listener.close()
        station.stop()
        camera.close()
        sim.close()
        code = daemon.stop()
        router.kill()
    assert code == 0, f"the daemon exited {code}; its log:\n{daemon.log_tail()}"


def strangers_of(listeners: dict[str, Listener]) -> dict[str, Listener]:
    return {name: listener for name, listener in listeners.items() if name != "station-certificate"}


def test_router_refuses_tls_listening_without_certificates(capsys) -> None:
    from gcs.router import main

    assert main(["--listen", "tls/127.0.0.1:7447"]) == 2
    assert "--tls-ca, --tls-cert and --tls-key" in capsys.readouterr().err


# ----- configuration: checked at start, the bad key named -----------------------------------------------

def zenoh_raw(**zenoh_keys: Any) -> dict[str, Any]:
    return {"source": {"kind": "zenoh"}, "tracker": {"name": "csrt", "range_size_band": 0}, "zenoh": zenoh_keys}


def tls_keys(pki_dir: Path, **changes: Any) -> dict[str, Any]:
    keys = {"enabled": True, "root_ca_certificate": str(pki_dir / "ca.crt"),
            "certificate": str(pki_dir / "drone-1.crt"), "private_key": str(pki_dir / "drone-1.key")}
    return {**keys, **changes}


@needs_openssl
def test_the_documented_recipe_makes_a_chain_openssl_verifies_with_the_drone_address(pki) -> None:
    ours = pki["ours"]
    for name in ("drone-1", "gcs", "viewer"):
        verify = subprocess.run(["openssl", "verify", "-CAfile", str(ours / "ca.crt"), str(ours / f"{name}.crt")],
                                capture_output=True, text=True)
        assert verify.returncode == 0, verify.stderr
    foreign = subprocess.run(["openssl", "verify", "-CAfile", str(ours / "ca.crt"), str(pki["other"] / "gcs.crt")],
                             capture_output=True, text=True)
    assert foreign.returncode != 0
    text = subprocess.run(["openssl", "x509", "-in", str(ours / "drone-1.crt"), "-noout", "-text"],
                          capture_output=True, text=True).stdout
    assert "IP Address:127.0.0.1" in text and "DNS:drone-1" in text and "CN = drone-1" in text


@needs_openssl
@pytest.mark.parametrize("change, message", [
    ({"root_ca_certificate": "missing-ca.crt"}, "zenoh.tls.root_ca_certificate: cannot read missing-ca.crt"),
    ({"private_key": ""}, "zenoh.tls.private_key: must name a PEM file"),
    ({"certificate": "NOT_PEM"}, "zenoh.tls.certificate: "),
    ({"enable_mtsl": True}, "zenoh.tls.enable_mtsl: unknown key"),
])
def test_bad_tls_settings_name_the_key(pki, tmp_path: Path, change: dict, message: str) -> None:
    if "certificate" in change:
        (tmp_path / "not.pem").write_text("hello")
        change = {"certificate": str(tmp_path / "not.pem")}
    with pytest.raises(ConfigError, match=re.escape(message)):
        config_from_mapping(zenoh_raw(listen=["tls/127.0.0.1:7447"], tls=tls_keys(pki["ours"], **change)))


def test_a_tls_endpoint_without_tls_settings_is_refused() -> None:
    with pytest.raises(ConfigError, match=re.escape("zenoh.listen[0]: tls/0.0.0.0:7447 is a TLS endpoint")):
        config_from_mapping(zenoh_raw(listen=["tls/0.0.0.0:7447"]))
    with pytest.raises(ConfigError, match=re.escape("zenoh.connect[0]: must be PROTOCOL/ADDRESS")):
        config_from_mapping(zenoh_raw(connect=["127.0.0.1:7447"]))


@pytest.mark.parametrize("edit, message", [
    (lambda a: a["rules"][0].update(messages=["publish"]), "zenoh.access.rules[0].messages: unknown 'publish'"),
    (lambda a: a["rules"][1].update(flows=["inbound"]), "zenoh.access.rules[1].flows: unknown 'inbound'"),
    (lambda a: a["rules"][2].update(key_exprs=["jsar//status"]), "zenoh.access.rules[2].key_exprs[0]: "),
    (lambda a: a["rules"][3].update(id="telemetry_out"), "zenoh.access.rules[3].id: 'telemetry_out' is used twice"),
    (lambda a: a["policies"][1].update(subjects=["viewers"]),
     "zenoh.access.policies[1].subjects: no subject with id 'viewers'"),
    (lambda a: a["subjects"][0].update(cert_common_names=[], interfaces=[]), "zenoh.access.subjects[0]: give "),
    (lambda a: a["subjects"][0].update(common_names=["gcs"]), "zenoh.access.subjects[0].common_names: unknown key"),
    (lambda a: a.update(policies=[]), "zenoh.access.policies: empty while default_permission is deny"),
])
def test_bad_access_lists_name_the_key(tmp_path: Path, edit, message: str) -> None:
    for name in ("ca.crt", "drone-1.crt", "drone-1.key"):
        (tmp_path / name).write_text("-----BEGIN X-----\n")  # only their being PEM files is checked here
    access = json.loads(json.dumps(access_list()))
    edit(access)
    with pytest.raises(ConfigError, match=re.escape(message)):
        config_from_mapping(zenoh_raw(tls=tls_keys(tmp_path), access=access))


def test_certificate_names_in_the_access_list_need_mutual_tls(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=re.escape("zenoh.access.subjects[0].cert_common_names: peers show "
                                                    "certificates only with zenoh.tls.enabled")):
        config_from_mapping(zenoh_raw(access=access_list()))


@needs_openssl
def test_the_checked_sections_are_what_zenoh_itself_accepts(pki) -> None:
    config = config_from_mapping(zenoh_raw(listen=["tls/127.0.0.1:7447"], tls=tls_keys(pki["ours"]),
                                           access=access_list()))
    section = access_control_section(config.zenoh.access)
    assert "cert_common_names" not in section["subjects"][2] and "id" not in section["policies"][0]
    zenoh_config(config.zenoh)  # Zenoh's own parser: an unknown key or value would raise here
    assert json.loads(str(zenoh_config(config.zenoh)))["transport"]["link"]["tls"]["enable_mtls"] is True


# ----- the warning for listening beyond loopback without TLS -------------------------------------------

def test_unencrypted_endpoints_beyond_loopback_are_named() -> None:
    loopback = ZenohConfig(listen=("tcp/127.0.0.1:7447", "tcp/localhost:7448", "tcp/[::1]:7449"))
    assert insecure_endpoints(loopback) == []
    exposed = ZenohConfig(listen=("tcp/127.0.0.1:7447", "tcp/0.0.0.0:7447"), connect=("udp/192.168.1.10:7447",))
    assert [(k, e) for k, e, _ in insecure_endpoints(exposed)] == [
        ("zenoh.listen[1]", "tcp/0.0.0.0:7447"), ("zenoh.connect[0]", "udp/192.168.1.10:7447")]
    open_tls = ZenohConfig(listen=("tls/0.0.0.0:7447",))
    assert [k for k, _, _ in insecure_endpoints(open_tls)] == []  # mTLS on by default
    no_mtls = ZenohConfig(listen=("tls/0.0.0.0:7447",), tls=ZenohTlsConfig(enable_mtls=False))
    assert [k for k, _, _ in insecure_endpoints(no_mtls)] == ["zenoh.tls.enable_mtls"]


def test_the_daemon_logs_the_key_when_it_listens_beyond_loopback_without_tls(caplog) -> None:
    # 192.0.2.1 (TEST-NET-1) is on no interface here: the listener cannot bind and nothing leaves the
    # machine, but the warning comes first, at start, naming the key
    config = ZenohConfig(listen=(f"tcp/192.0.2.1:{free_tcp_port()}",))
    caplog.set_level(logging.WARNING, logger="service.telemetry")
    with pytest.raises(ConnectionError):
        open_session(config).close()
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("event=zenoh_unencrypted key=zenoh.listen[0]" in w and "without TLS" in w for w in warnings), warnings


# ----- the ground side: the same settings -----------------------------------------------------------------

def test_ground_station_options_need_certificates_for_tls_endpoints(tmp_path: Path) -> None:
    from gcs.web.__main__ import parse_args
    from gcs.zenoh_tls import tls_from_args

    with pytest.raises(ValueError, match="--zenoh-tls-ca, --zenoh-tls-cert and --zenoh-tls-key"):
        ZenohSettings(connect=("tls/192.168.1.20:7447",))
    args = parse_args(["--mavlink", "udpin:127.0.0.1:14550", "--zenoh", "tls/192.168.1.20:7447",
                       "--zenoh-tls-ca", str(tmp_path / "ca.crt"), "--zenoh-tls-cert", str(tmp_path / "gcs.crt"),
                       "--zenoh-tls-key", str(tmp_path / "gcs.key")])
    with pytest.raises(ValueError, match=re.escape(f"--zenoh-tls-ca: cannot read {tmp_path / 'ca.crt'}")):
        tls_from_args(args, "--zenoh-tls")
    assert ZenohSettings(connect=("tcp/192.168.1.20:7447",)).unencrypted()[0].startswith("tcp/192.168.1.20:7447 "
                                                                                       "reaches beyond loopback")


def test_router_access_list_is_checked_by_zenoh_and_the_key_named() -> None:
    bad = access_list()
    bad["rules"][0]["messages"] = ["publish"]
    with pytest.raises(ValueError, match="--access: .*unknown variant `publish`"):
        router_config(["tcp/127.0.0.1:7447"], False, None, bad)
