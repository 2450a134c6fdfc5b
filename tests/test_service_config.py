"""Configuration: the documented default loads; every bad key / value stops with its key path."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import jsar
import yaml

from service.config import ConfigError, config_from_mapping, load_config, with_overrides

REPO = Path(__file__).resolve().parents[1]


def test_documented_default_config_loads_and_matches_dataclass_defaults() -> None:
    config = load_config(REPO / "config.yaml")
    assert config.mavlink.component_id == 100
    assert config.guidance.mode == "off"
    assert config.source.kind == "v4l2"
    # every key of the dataclasses is documented in config.yaml (no hidden settings)
    documented = yaml.safe_load((REPO / "config.yaml").read_text())
    from service.config import as_plain
    def keys(d: dict, prefix: str = "") -> set[str]:
        out = set()
        for k, v in d.items():
            out |= keys(v, f"{prefix}{k}.") if isinstance(v, dict) and k != "params" else {prefix + k}
        return out
    assert keys(as_plain(config)) == keys(documented)


@pytest.mark.parametrize("raw, message", [
    ({"gimbal": {"max_rate_deg_s": -3}}, "gimbal.max_rate_deg_s: must be > 0, got -3"),
    ({"gimbal": {"backend": "dji"}}, "gimbal.backend: must be one of ardupilot, px4, none, got 'dji'"),
    ({"gimbal": {"kp": "fast"}}, "gimbal.kp: must be a number"),
    ({"gimbal": {"kp": float("nan")}}, "gimbal.kp: must be finite"),
    ({"gimbal": {"speed": 1}}, "gimbal.speed: unknown key"),
    ({"colour": {}}, "colour: unknown key"),
    ({"mavlink": {"component_id": 1}}, "mavlink.component_id: must be in [100, 105], got 1"),
    ({"mavlink": {"signing": {"link_id": 300}}}, "mavlink.signing.link_id: must be in [0, 255], got 300"),
    ({"mavlink": {"system_id": 1.5}}, "mavlink.system_id: must be an integer"),
    ({"mavlink": {"url": ""}}, "mavlink.url: '' is not a MAVLink link; accepted forms: udpout:HOST:PORT"),
    ({"mavlink": {"url": "foo:bar"}}, "mavlink.url: 'foo:bar' is not a MAVLink link; accepted forms: udpout:HOST:PORT"),
    ({"mavlink": {"url": "udpout:10.0.0.1"}}, "mavlink.url: 'udpout:10.0.0.1' is not a MAVLink link"),
    ({"mavlink": {"url": "udpout:10.0.0.1:70000"}}, "mavlink.url: 'udpout:10.0.0.1:70000' is not a MAVLink link"),
    ({"mavlink": {"url": "tcp::5760"}}, "mavlink.url: 'tcp::5760' is not a MAVLink link"),
    ({"mavlink": {"url": "udpout://127.0.0.1"}}, "mavlink.url: 'udpout://127.0.0.1' is not a MAVLink link"),
    ({"mavlink": {"url": "udpout://:14550"}}, "mavlink.url: 'udpout://:14550' is not a MAVLink link"),
    ({"mavlink": {"url": "udpout:///127.0.0.1:14550"}}, "mavlink.url: 'udpout:///127.0.0.1:14550' is not a MAVLink"),
    ({"mavlink": {"url": "udpout:/127.0.0.1:14550"}}, "mavlink.url: 'udpout:/127.0.0.1:14550' is not a MAVLink link"),
    ({"mavlink": {"url": "tcp://10.0.0.1:5760/x"}}, "mavlink.url: 'tcp://10.0.0.1:5760/x' is not a MAVLink link"),
    ({"mavlink": {"url": "udp://127.0.0.1:14550"}}, "mavlink.url: 'udp://127.0.0.1:14550' is not a MAVLink link"),
    ({"source": {"kind": "file"}}, "source.path: must name a video file or an image folder"),
    ({"source": {"kind": "v4l2", "fourcc": "MJPEG"}}, "source.fourcc: must be 4 characters"),
    ({"source": {"retry_initial_s": 2.0, "retry_max_s": 1.0}}, "source.retry_max_s: must be >= source.retry_initial_s"),
    ({"source": {"loop": "yes"}}, "source.loop: must be true or false"),
    ({"zenoh": {"listen": "tcp/127.0.0.1:7447"}}, "zenoh.listen: must be a list"),
    ({"zenoh": {"prefix": "/jsar"}}, "zenoh.prefix: must be non-empty without leading/trailing '/'"),
    ({"zenoh": {"enabled": False}, "source": {"kind": "zenoh"}}, "zenoh.enabled: must be true when source.kind is zenoh"),
    ({"tracker": {"name": "magic"}}, "tracker.name: unknown tracker 'magic'"),
    ({"guidance": {"rate_hz": 1.0}}, "guidance.rate_hz: must be in [2.5, 50.0], got 1.0"),
    ({"camera": {"hfov_deg": 0}}, "camera.hfov_deg: must be in [1.0, 179.0], got 0"),
    ({"camera": {"rectangle_loose_area_ratio": 0.5}}, "camera.rectangle_loose_area_ratio: must be >= 1, got 0.5"),
    ({"camera": {"rectangle_fit_min_inside": 0.2}}, "camera.rectangle_fit_min_inside: must be in [0.5, 1.0], got 0.2"),
    ({"logging": {"level": "LOUD"}}, "logging.level: must be one of DEBUG, INFO, WARNING, ERROR"),
    ({"tracker": {"verifier_thread": "yes"}}, "tracker.verifier_thread: must be one of true, false, auto, got 'yes'"),
    ({"tracker": {"verifier_thread": 1}}, "tracker.verifier_thread: must be one of true, false, auto, got 1"),
    ([1, 2], "config: must be a mapping"),
])
def test_bad_values_are_rejected_naming_the_key(raw: object, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        config_from_mapping(raw)
    assert message in str(info.value)


def test_command_line_overrides_pick_the_source_kind() -> None:
    base = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}})
    assert with_overrides(base, source="/dev/video2").source.device == "/dev/video2"
    assert with_overrides(base, source="zenoh").source.kind == "zenoh"
    as_file = with_overrides(base, source="clip.avi", mavlink_url="tcp:10.0.0.1:5760")
    assert (as_file.source.kind, as_file.source.path, as_file.mavlink.url) == ("file", "clip.avi", "tcp:10.0.0.1:5760")


@pytest.mark.parametrize("url", ["udpout:127.0.0.1:14555", "udpin:0.0.0.0:14550", "tcp:10.0.0.1:5760",
                                 "tcpin:0.0.0.0:5760", "/dev/ttyAMA0", "/dev/serial/by-id/usb-ArduPilot"])
def test_accepted_mavlink_url_forms(url: str) -> None:
    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0}, "mavlink": {"url": url}})
    assert config.mavlink.url == url


@pytest.mark.parametrize("url, pymavlink_form", [
    ("udpout://127.0.0.1:14550", "udpout:127.0.0.1:14550"), ("udpin://0.0.0.0:14550", "udpin:0.0.0.0:14550"),
    ("tcp://10.0.0.1:5760", "tcp:10.0.0.1:5760"), ("tcpin://0.0.0.0:5760", "tcpin:0.0.0.0:5760")])
def test_the_url_form_of_a_network_link_becomes_pymavlink_form(tmp_path: Path, url: str, pymavlink_form: str) -> None:
    """`--mavlink udpout://HOST:PORT` as `jsar-gcs --url` (mavsdk) takes it: accepted from the command line
    and from the file, and stored as pymavlink's `udpout:HOST:PORT` (pymavlink took '//HOST' for the host)."""
    base = {"tracker": {"name": "csrt", "range_size_band": 0}}
    assert config_from_mapping({**base, "mavlink": {"url": url}}).mavlink.url == pymavlink_form
    assert with_overrides(config_from_mapping(base), mavlink_url=url).mavlink.url == pymavlink_form
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(base))
    assert load_config(path, mavlink_url=url).mavlink.url == pymavlink_form


def test_command_line_overrides_are_applied_before_validation(tmp_path: Path) -> None:
    """`source: {kind: file}` with its path on the command line, and a bad URL in the file replaced by a
    good one on the command line: both complete only after the overrides."""
    path = tmp_path / "partial.yaml"
    path.write_text("source:\n  kind: file\nmavlink:\n  url: not-a-url\ntracker:\n  name: csrt\n  range_size_band: 0\n")
    config = load_config(path, source="clip.avi", mavlink_url="udpout:127.0.0.1:14550")
    assert (config.source.kind, config.source.path, config.mavlink.url) == ("file", "clip.avi", "udpout:127.0.0.1:14550")
    with pytest.raises(ConfigError, match="source.path: must name a video file"):
        load_config(path, mavlink_url="udpout:127.0.0.1:14550")  # no --source: the file alone is incomplete
    with pytest.raises(ConfigError, match="mavlink.url: 'not-a-url'"):
        load_config(path, source="clip.avi")


def _run_service(args: list[str], timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "service", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout_s, env=dict(os.environ, MAVLINK20="1"))


def test_daemon_reports_every_configuration_error_in_one_form(tmp_path: Path) -> None:
    """A malformed --mavlink URL (found while loading) and tracker.params the tracker refuses (found while
    building the parts): both `jsar-service: configuration error: <key>: ...` on stderr, exit code 2."""
    clip = tmp_path / "frames"
    clip.mkdir()
    base = tmp_path / "base.yaml"
    base.write_text("source:\n  kind: file\nzenoh:\n  enabled: false\ntracker:\n  name: csrt\n  range_size_band: 0\n")
    url = _run_service(["--config", str(base), "--source", str(clip), "--mavlink", "foo:bar"])
    assert url.returncode == 2, url.stderr
    assert url.stderr.startswith("jsar-service: configuration error: mavlink.url: 'foo:bar' is not a MAVLink link; "
                                 "accepted forms: udpout:HOST:PORT"), url.stderr
    params = tmp_path / "params.yaml"
    params.write_text(base.read_text().replace("  range_size_band: 0\n", "  range_size_band: 0\n  params: {foo: 1}\n"))
    bad = _run_service(["--config", str(params), "--source", str(clip)])
    assert bad.returncode == 2, bad.stderr
    assert bad.stderr.strip().splitlines()[-1].startswith("jsar-service: configuration error: tracker.params: "), bad.stderr
    assert "foo" in bad.stderr


def test_a_missing_source_file_or_folder_is_a_configuration_error(tmp_path: Path) -> None:
    """A --source file or image folder that is not there at start (a typo) stops the daemon, exit code 2,
    naming source.path; before, it looked like a failing camera, retried for ever."""
    base = tmp_path / "base.yaml"
    base.write_text("zenoh:\n  enabled: false\ntracker:\n  name: csrt\n  range_size_band: 0\n")
    clip = tmp_path / "x.avi"
    proc = _run_service(["--config", str(base), "--source", str(clip), "--mavlink", "udpout:127.0.0.1:14550"])
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == \
        f"jsar-service: configuration error: source.path: no such file or folder: '{clip}'", proc.stderr
    assert "event=started" not in proc.stderr
    from service.app import Service
    folder = tmp_path / "no_frames"
    with pytest.raises(ConfigError, match=f"^source.path: no such file or folder: '{re.escape(str(folder))}'$"):
        Service(config_from_mapping({**yaml.safe_load(base.read_text()),
                                     "source": {"kind": "file", "path": str(folder)}}))


def test_daemon_exits_2_naming_the_key_on_a_bad_config(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("gimbal:\n  max_rate_deg_s: -3\n")
    proc = subprocess.run([sys.executable, "-m", "service", "--config", str(bad)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "gimbal.max_rate_deg_s: must be > 0, got -3" in proc.stderr


def test_missing_or_malformed_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(tmp_path / "absent.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("gimbal: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(broken)


def test_bad_tracker_params_stop_the_service_naming_the_key() -> None:
    from service.app import Service
    config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0, "params": {"no_such_param": 1}},
                                  "zenoh": {"enabled": False}})
    with pytest.raises(ConfigError, match="tracker.params: .*no_such_param"):
        Service(config)


def test_nested_jsar_re_params_reach_the_tracker_and_a_bad_one_is_named(tmp_path: Path) -> None:
    from service.app import Service
    good = tmp_path / "good.yaml"
    good.write_text("tracker:\n  name: jsar-re\n  params:\n    redetect:\n      search: {windows_per_frame: 2}\n"
                    "zenoh: {enabled: false}\n")
    config = load_config(good)
    tracker = jsar.create(config.tracker.name, **config.tracker.params)
    assert tracker.redetect.search.windows_per_frame == 2
    bad = config_from_mapping({"tracker": {"name": "jsar-re", "params": {"redetect": {"accept": {"holdoff": 3}}}},
                               "zenoh": {"enabled": False}})
    with pytest.raises(ConfigError, match=r"tracker.params: unknown key redetect.accept.holdoff"):
        Service(bad)


@pytest.mark.parametrize("name, band, error", [("csrt", 1.6, "tracker.range_size_band: tracker 'csrt' cannot"),
                                               ("jsar-re", 0.5, "tracker.range_size_band: must be 0 .off. or >= 1")])
def test_range_size_band_is_refused_where_it_cannot_work(name, band, error) -> None:
    from service.app import Service
    with pytest.raises(ConfigError, match=error):
        Service(config_from_mapping({"tracker": {"name": name, "range_size_band": band}, "zenoh": {"enabled": False}}))
