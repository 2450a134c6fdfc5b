"""The service's one typed configuration: nested frozen dataclasses loaded from YAML.

Every key is validated at start. Unknown keys are rejected and every error names the key path,
e.g. ``gimbal.max_rate_deg_s: must be > 0, got -3``. Defaults are the documented defaults of the
top-level ``config.yaml``. Units are in the key names (``_deg``, ``_s``, ``_hz``, ``_m``);
"fraction" means a fraction of the image width.
"""
from __future__ import annotations

import collections.abc
import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping

import yaml

from jsar.checked import checked as _checked, in_range as _in_range, non_negative as _non_negative, positive as _positive


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range; the message names the key path."""


@dataclass(frozen=True)
class SourceConfig:
    """Where frames come from. `kind` v4l2: device; file: path (video file or image folder); zenoh."""

    kind: Literal["v4l2", "file", "zenoh"] = "v4l2"
    device: str = "/dev/video0"
    path: str = ""
    width: int = _checked(640, _positive)  # v4l2 requested capture size, pixels
    height: int = _checked(480, _positive)
    fps: float = _checked(30.0, _positive)  # v4l2 requested rate; image-folder pacing rate
    fourcc: str = "MJPG"
    realtime: bool = True  # file: pace at the file's own frame rate, like a camera
    loop: bool = False  # file: start again at the end instead of reporting end of file
    retry_initial_s: float = _checked(0.5, _positive)  # first reconnect delay after a failure
    retry_max_s: float = _checked(8.0, _positive)  # backoff doubles up to this delay


# A Pi 4 has four cores: the tracking thread, the verifier's, and the service's capture and video keep two busy
# (docs/results-cost.md); on two cores the verifier's thread competes with the tracking thread (docs/service.md).
VERIFIER_THREAD_MIN_CPUS = 4


@dataclass(frozen=True)
class TrackerConfig:
    """`jsar.create(name, **params)`; an unknown name is a configuration error."""

    name: str = "jsar-re"
    params: Mapping[str, Any] = field(default_factory=lambda: types.MappingProxyType({}))
    threads: int = _checked(1, _positive)  # OpenCV and BLAS/OpenMP threads for the tracker
    # jsar-re's deferred verifier work (learning, watch checks) and part of a lost frame's search on a thread of its
    # own, another core: true, false, or auto = on where the service may run on >= VERIFIER_THREAD_MIN_CPUS CPUs
    # (docs/service.md: when)
    verifier_thread: Literal[True, False, "auto"] = "auto"
    # Box side held within [1/band, band] x the track's median ground size at the current range (flat
    # ground, pose and gimbal attitude from the autopilot); 0 = off. See service.control.size_bound.
    range_size_band: float = _checked(1.6, lambda v: None if v == 0 or v >= 1 else f"must be 0 (off) or >= 1, got {v}")
    range_size_sample_s: float = _checked(1.0, _positive)  # one ground-size sample per this many seconds ...
    range_size_samples: int = _checked(600, _positive)  # ... the median of the last this many is the reference


@dataclass(frozen=True)
class CameraConfig:
    """Optics and identity of the tracking camera, and how a clicked point or a dragged rectangle becomes a box."""

    hfov_deg: float = _checked(70.0, _in_range(1.0, 179.0))  # horizontal field of view
    default_point_radius: float = _checked(0.04, _in_range(0.001, 0.5))  # fraction of width when radius = 0
    min_box_px: float = _checked(12.0, _positive)  # smallest box side (pixels) of a point or a fitted rectangle
    point_proposal: bool = True  # a point's box: the EdgeBoxes proposal around the object under it (else the square)
    # TRACK_RECTANGLE: a loose rectangle is replaced by the EdgeBoxes proposal of the object inside it
    # (service.selection.fitted_rectangle_box); else the rectangle as dragged.
    rectangle_fit: bool = True
    # "loose": rectangle area >= this * the fitted box's area (ratio of areas); a tighter rectangle is kept
    rectangle_loose_area_ratio: float = _checked(1.5, lambda v: None if v >= 1 else f"must be >= 1, got {v}")
    # "fits": the proposal covers at least this fraction of the rectangle's area (smaller ones are parts) ...
    rectangle_fit_min_area_fraction: float = _checked(0.0625, _in_range(0.001, 1.0))
    # ... and at least this fraction of the proposal's area lies inside the rectangle
    rectangle_fit_min_inside: float = _checked(0.9, _in_range(0.5, 1.0))
    # ... and its colours differ from its surround's by at least this (chi-square histogram distance, 0..1)
    rectangle_fit_min_contrast: float = _checked(0.02, _in_range(0.0, 1.0))
    vendor_name: str = "JSAR"
    model_name: str = "jsar-tracker"


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 signing: off when key_file is empty. The key file holds 32 raw bytes or 64 hex chars."""

    key_file: str = ""
    allow_unsigned: bool = False  # accept unsigned packets too (migration); rejected by default
    link_id: int = _checked(0, _in_range(0, 255))


@dataclass(frozen=True)
class MavlinkConfig:
    """The one MAVLink link (pymavlink connection string; `udpout://HOST:PORT` and the like are taken as
    `udpout:HOST:PORT`) and the camera component's identity."""

    url: str = "udpout:127.0.0.1:14555"
    baud: int = _checked(921600, _positive)  # serial devices only
    system_id: int = _checked(0, _in_range(0, 255))  # 0 = learn from the autopilot's heartbeat
    provisional_system_id: int = _checked(1, _in_range(1, 255))  # used until it is learned
    component_id: int = _checked(100, _in_range(100, 105))  # MAV_COMP_ID_CAMERA .. CAMERA6
    heartbeat_timeout_s: float = _checked(3.0, _positive)  # autopilot considered gone after this
    default_status_interval_s: float = _checked(0.1, _positive)  # 275 interval when asked for "default"
    signing: SigningConfig = field(default_factory=SigningConfig)


@dataclass(frozen=True)
class GimbalConfig:
    """PI(D) on angular error (radians) -> gimbal rates; gains in SI (rad/s per rad, ...)."""

    backend: Literal["ardupilot", "px4", "none"] = "ardupilot"
    device_id: int = _checked(0, _in_range(0, 255))  # 0 = primary gimbal
    kp: float = _checked(2.0, _non_negative)  # 1/s
    ki: float = _checked(0.4, _non_negative)  # 1/s^2
    kd: float = _checked(0.0, _non_negative)  # dimensionless (s * 1/s)
    max_rate_deg_s: float = _checked(60.0, _positive)
    max_accel_deg_s2: float = _checked(400.0, _positive)  # slew limit on the commanded rate
    integrator_limit_deg_s: float = _checked(15.0, _non_negative)  # |ki * integral| bound
    deadband_deg: float = _checked(0.0, _non_negative)
    claim_interval_s: float = _checked(1.0, _positive)  # px4: re-send the claim while not primary
    # how GIMBAL_DEVICE_ATTITUDE_STATUS is to be read: "earth" (MAVLink's definition: roll and pitch against the
    # horizon) or "body" (angles against the vehicle's body: ArduPilot's servo mount, MNT1_TYPE 1, reports so)
    attitude_frame: Literal["earth", "body"] = "earth"
    # while lost: point at the target's predicted ground position for coast_s, then hold (control.coast)
    coast_s: float = _checked(3.0, _in_range(0.0, 10.0))  # 0 = hold at once (no coasting)
    coast_fit_s: float = _checked(1.0, _in_range(0.1, 5.0))  # confident history the rate is fitted on
    # a loss within coast_fit_s of the re-acquisition that ended a coast, or one whose cause refutes the track (drift,
    # appearance), resumes that coast when the velocity fitted now differs from its velocity by more than this (m/s,
    # ground): the track followed something else
    coast_resume_change_m_s: float = _checked(2.0, _in_range(0.1, 100.0))


@dataclass(frozen=True)
class GuidanceConfig:
    """Vehicle guidance, off by default. Never arms, never changes modes."""

    mode: Literal["off", "velocity", "follow_target"] = "off"
    rate_hz: float = _checked(10.0, _in_range(2.5, 50.0))  # > 2 Hz: PX4 offboard needs it
    yaw_gain: float = _checked(1.0, _non_negative)  # yaw rate per rad of target bearing, 1/s
    max_yaw_rate_deg_s: float = _checked(30.0, _positive)
    forward_gain: float = _checked(0.3, _non_negative)  # m/s per m of range error
    max_speed_m_s: float = _checked(5.0, _positive)
    follow_distance_m: float = _checked(15.0, _positive)  # desired ground range to the target


# the message kinds of Zenoh 1.x access-control rules (access_control.rules[].messages)
ZENOH_ACL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                      "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
ZENOH_ACL_FLOWS = ("ingress", "egress")


@dataclass(frozen=True)
class ZenohTlsConfig:
    """Zenoh's own TLS link (transport.link.tls) for `tls/HOST:PORT` endpoints: PEM file paths (docs/security.md)."""

    enabled: bool = False
    root_ca_certificate: str = ""  # the CA that signed every peer's certificate
    certificate: str = ""  # this node's certificate, shown when listening and when connecting
    private_key: str = ""  # its private key (unencrypted PEM)
    enable_mtls: bool = True  # a peer must show a certificate signed by root_ca_certificate to connect
    verify_name_on_connect: bool = True  # a connect endpoint's host must be named in the peer's certificate (SAN)


@dataclass(frozen=True)
class ZenohAclRule:
    """One access-control rule (Zenoh access_control.rules[]): allow or deny `messages` on `key_exprs`."""

    id: str = ""
    permission: Literal["allow", "deny"] = "allow"
    messages: tuple[str, ...] = ()  # of ZENOH_ACL_MESSAGES
    flows: tuple[str, ...] = ZENOH_ACL_FLOWS  # ingress: from the peer to this node; egress: from this node to it
    key_exprs: tuple[str, ...] = ()


@dataclass(frozen=True)
class ZenohAclSubject:
    """Peers a policy applies to (access_control.subjects[]): a peer matches when it matches one value of
    every list given (certificate common name of an mTLS peer, network interface, link protocol)."""

    id: str = ""
    cert_common_names: tuple[str, ...] = ()
    interfaces: tuple[str, ...] = ()
    link_protocols: tuple[str, ...] = ()


@dataclass(frozen=True)
class ZenohAclPolicy:
    """Rules (by id) applied to subjects (by id) (access_control.policies[])."""

    id: str = ""
    rules: tuple[str, ...] = ()
    subjects: tuple[str, ...] = ()


@dataclass(frozen=True)
class ZenohAccessConfig:
    """Zenoh's access control (access_control): what each peer may send to / receive from this node."""

    enabled: bool = False
    default_permission: Literal["allow", "deny"] = "deny"  # for messages no policy matches
    rules: tuple[ZenohAclRule, ...] = ()
    subjects: tuple[ZenohAclSubject, ...] = ()
    policies: tuple[ZenohAclPolicy, ...] = ()


@dataclass(frozen=True)
class ZenohConfig:
    """Telemetry / frames over Zenoh; keys under `prefix`."""

    enabled: bool = True
    mode: Literal["peer", "client"] = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    prefix: str = "jsar"
    tls: ZenohTlsConfig = field(default_factory=ZenohTlsConfig)
    access: ZenohAccessConfig = field(default_factory=ZenohAccessConfig)


@dataclass(frozen=True)
class PreviewConfig:
    """Tracked frames as JPEG over Zenoh on <prefix>/camera/preview (only while zenoh.enabled)."""

    enabled: bool = True
    max_width_px: int = _checked(640, _positive)  # scaled down to fit inside, aspect kept, never enlarged
    max_height_px: int = _checked(480, _positive)
    max_fps: float = _checked(15.0, _positive)  # frames thinned to at most this rate
    jpeg_quality: int = _checked(70, _in_range(1, 100))


@dataclass(frozen=True)
class StreamConfig:
    """Tracked frames as H.264 over RTP/UDP to a ground station (QGroundControl listens on UDP 5600)."""

    enabled: bool = False
    host: str = ""  # the ground station's address (IPv4 or name); required when enabled
    port: int = _checked(5600, _in_range(1, 65535))  # RTP; RTCP goes to port + 1
    max_width_px: int = _checked(640, _positive)  # scaled down to fit inside (even sizes), never enlarged
    max_height_px: int = _checked(480, _positive)
    fps: float = _checked(30.0, _in_range(1.0, 120.0))  # frames thinned to at most this rate
    bitrate_kbps: int = _checked(2000, _in_range(100, 50000))  # H.264 target bit rate
    keyframe_interval_s: float = _checked(1.0, _in_range(0.1, 10.0))  # a late-joining viewer waits up to this


@dataclass(frozen=True)
class VideoConfig:
    """Video out of the daemon, encoded off the tracking thread (latest frame wins, drops counted)."""

    preview: PreviewConfig = field(default_factory=PreviewConfig)
    stream: StreamConfig = field(default_factory=StreamConfig)


@dataclass(frozen=True)
class LoggingConfig:
    """Structured logs on stderr (journald picks them up)."""

    level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    format: Literal["kv", "json"] = "kv"


@dataclass(frozen=True)
class ServiceConfig:
    """The whole service configuration (top-level config.yaml)."""

    source: SourceConfig = field(default_factory=SourceConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    gimbal: GimbalConfig = field(default_factory=GimbalConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)


def load_config(path: str | Path, source: str | None = None, mavlink_url: str | None = None) -> ServiceConfig:
    """Read a YAML file, apply the command-line overrides (see `apply_overrides`), then validate the
    result: ConfigError naming the file or the key path on any problem. Overrides come before the checks,
    so `source: {kind: file}` without a path plus `--source FILE` is a complete configuration."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:  # a binary file, or another encoding than UTF-8
        raise ConfigError(f"config file {path} is not UTF-8 text: byte {exc.start} is "
                          f"0x{exc.object[exc.start]:02x}") from exc
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {path} is not valid YAML: {exc}") from exc
    except RecursionError as exc:  # PyYAML composes nested collections recursively
        raise ConfigError(f"config file {path} nests lists or mappings too deeply to read") from exc
    return config_from_mapping(apply_overrides({} if raw is None else raw, source, mavlink_url))


def config_from_mapping(raw: object) -> ServiceConfig:
    """Build and validate a ServiceConfig from plain data (as parsed YAML)."""
    config = _build(ServiceConfig, raw, "")
    _check_cross_fields(config)
    return _normalised(config)


def source_override(source: str) -> dict[str, str]:
    """--source value -> source keys: `zenoh`, a /dev/video* device (v4l2), else a file or image folder."""
    if source == "zenoh":
        return {"kind": "zenoh"}
    if source.startswith("/dev/video"):
        return {"kind": "v4l2", "device": source}
    return {"kind": "file", "path": source}


def apply_overrides(raw: object, source: str | None = None, mavlink_url: str | None = None) -> object:
    """A copy of the parsed YAML with the command-line overrides (--source, --mavlink) put into its
    `source` and `mavlink` sections; a section that is not a mapping is left for validation to report."""
    if not isinstance(raw, Mapping):
        return raw
    merged = dict(raw)
    for section, values in (("source", source_override(source) if source is not None else None),
                            ("mavlink", {"url": mavlink_url} if mavlink_url is not None else None)):
        if values is None:
            continue
        current = merged.get(section)
        if current is None:
            current = {}
        if isinstance(current, Mapping):
            merged[section] = {**current, **values}
    return merged


def with_overrides(config: ServiceConfig, source: str | None = None, mavlink_url: str | None = None) -> ServiceConfig:
    """Apply the command-line overrides to a built config: --source (device, file/folder or `zenoh`) and
    --mavlink URL (the daemon uses load_config(path, source, mavlink_url), which validates after them)."""
    if source is not None:
        config = dataclasses.replace(config, source=dataclasses.replace(config.source, **source_override(source)))
    if mavlink_url is not None:
        config = dataclasses.replace(config, mavlink=dataclasses.replace(config.mavlink, url=mavlink_url))
    _check_cross_fields(config)
    return _normalised(config)


def as_plain(config: ServiceConfig) -> dict[str, Any]:
    """The effective configuration as plain JSON-able data (tuples -> lists)."""
    def plain(value: Any) -> Any:
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        if isinstance(value, Mapping):
            return {str(k): plain(v) for k, v in value.items()}
        return value
    return plain(config)


def _normalised(config: ServiceConfig) -> ServiceConfig:
    """A checked config with its values in the one form the adapters take: mavlink.url in pymavlink's
    `scheme:HOST:PORT` (see normalise_mavlink_url)."""
    url = normalise_mavlink_url(config.mavlink.url)
    if url == config.mavlink.url:
        return config
    return dataclasses.replace(config, mavlink=dataclasses.replace(config.mavlink, url=url))


def _check_cross_fields(config: ServiceConfig) -> None:
    """Checks that involve several keys."""
    src = config.source
    if src.kind == "file" and not src.path:
        raise ConfigError("source.path: must name a video file or an image folder when source.kind is file")
    if src.kind == "v4l2" and not src.device:
        raise ConfigError("source.device: must name a device when source.kind is v4l2")
    if src.kind == "v4l2" and len(src.fourcc) != 4:
        raise ConfigError(f"source.fourcc: must be 4 characters, got {src.fourcc!r}")
    if src.retry_max_s < src.retry_initial_s:
        raise ConfigError(f"source.retry_max_s: must be >= source.retry_initial_s ({src.retry_initial_s}), "
                          f"got {src.retry_max_s}")
    problem = mavlink_url_problem(config.mavlink.url)
    if problem:
        raise ConfigError(f"mavlink.url: {problem}")
    if not config.zenoh.prefix or config.zenoh.prefix.strip("/") != config.zenoh.prefix:
        raise ConfigError(f"zenoh.prefix: must be non-empty without leading/trailing '/', got {config.zenoh.prefix!r}")
    if src.kind == "zenoh" and not config.zenoh.enabled:
        raise ConfigError("zenoh.enabled: must be true when source.kind is zenoh")
    _check_zenoh_security(config.zenoh)
    stream = config.video.stream
    if stream.enabled and not stream.host:
        raise ConfigError("video.stream.host: must name the ground station's address when video.stream.enabled is true")
    if stream.enabled and (any(c.isspace() for c in stream.host) or "/" in stream.host or ":" in stream.host):
        raise ConfigError(f"video.stream.host: must be an IPv4 address or a host name (no port, no scheme), "
                          f"got {stream.host!r}")
    from jsar.registry import available  # lazily: keeps config parsing importable on its own

    names = available()
    if config.tracker.name not in names:
        raise ConfigError(f"tracker.name: unknown tracker {config.tracker.name!r}; available: {', '.join(names)}")


def endpoint_protocol(endpoint: str) -> str:
    """`tls/HOST:PORT` -> "tls" (a Zenoh endpoint's protocol; "" when there is no `/`)."""
    protocol, slash, _ = endpoint.partition("/")
    return protocol if slash else ""


def _check_pem_file(key_path: str, path: str) -> None:
    """ConfigError naming `key_path` unless `path` names a readable PEM file."""
    if not path:
        raise ConfigError(f"{key_path}: must name a PEM file when zenoh.tls.enabled is true")
    try:
        head = Path(path).read_bytes()[:65536]
    except OSError as exc:
        raise ConfigError(f"{key_path}: cannot read {path}: {exc.strerror}") from exc
    if b"-----BEGIN " not in head:
        raise ConfigError(f"{key_path}: {path} is not a PEM file (no -----BEGIN line)")


def _check_zenoh_security(zenoh: ZenohConfig) -> None:
    """zenoh.tls: files readable when on, tls/ endpoints only with it; zenoh.access: known messages and flows,
    valid key expressions, unique ids, policies naming existing rules and subjects."""
    tls = zenoh.tls
    for section in ("listen", "connect"):
        for i, endpoint in enumerate(getattr(zenoh, section)):
            if endpoint_protocol(endpoint) == "":
                raise ConfigError(f"zenoh.{section}[{i}]: must be PROTOCOL/ADDRESS (tcp/HOST:PORT, tls/HOST:PORT), "
                                  f"got {endpoint!r}")
            if endpoint_protocol(endpoint) == "tls" and not tls.enabled:
                raise ConfigError(f"zenoh.{section}[{i}]: {endpoint} is a TLS endpoint: set zenoh.tls.enabled: true "
                                  "and its certificate files")
    if tls.enabled:
        for name in ("root_ca_certificate", "certificate", "private_key"):
            _check_pem_file(f"zenoh.tls.{name}", getattr(tls, name))
    access = zenoh.access
    rule_ids = _unique_ids("zenoh.access.rules", [r.id for r in access.rules])
    subject_ids = _unique_ids("zenoh.access.subjects", [s.id for s in access.subjects])
    for i, rule in enumerate(access.rules):
        where = f"zenoh.access.rules[{i}]"
        for name, values, known in (("messages", rule.messages, ZENOH_ACL_MESSAGES),
                                    ("flows", rule.flows, ZENOH_ACL_FLOWS)):
            if not values:
                raise ConfigError(f"{where}.{name}: must list at least one of {', '.join(known)}")
            unknown = [v for v in values if v not in known]
            if unknown:
                raise ConfigError(f"{where}.{name}: unknown {unknown[0]!r}; known: {', '.join(known)}")
        if not rule.key_exprs:
            raise ConfigError(f"{where}.key_exprs: must list at least one key expression (e.g. jsar/track)")
        for j, expr in enumerate(rule.key_exprs):
            problem = _key_expr_problem(expr)
            if problem:
                raise ConfigError(f"{where}.key_exprs[{j}]: {problem}")
    for i, subject in enumerate(access.subjects):
        where = f"zenoh.access.subjects[{i}]"
        if not (subject.cert_common_names or subject.interfaces or subject.link_protocols):
            raise ConfigError(f"{where}: give cert_common_names, interfaces or link_protocols (a subject matching "
                              "nothing never applies)")
        if subject.cert_common_names and not (tls.enabled and tls.enable_mtls):
            raise ConfigError(f"{where}.cert_common_names: peers show certificates only with zenoh.tls.enabled and "
                              "zenoh.tls.enable_mtls true")
    for i, policy in enumerate(access.policies):
        where = f"zenoh.access.policies[{i}]"
        for name, refs, known in (("rules", policy.rules, rule_ids), ("subjects", policy.subjects, subject_ids)):
            if not refs:
                raise ConfigError(f"{where}.{name}: must name at least one id of zenoh.access.{name}")
            missing = [r for r in refs if r not in known]
            if missing:
                raise ConfigError(f"{where}.{name}: no {name[:-1]} with id {missing[0]!r} "
                                  f"(ids: {', '.join(known) or 'none'})")
    if access.enabled and not access.policies and access.default_permission == "deny":
        raise ConfigError("zenoh.access.policies: empty while default_permission is deny: every peer would be "
                          "refused everything")


def _unique_ids(where: str, ids: list[str]) -> list[str]:
    """The ids, ConfigError naming the entry when one is empty or repeated."""
    for i, ident in enumerate(ids):
        if not ident:
            raise ConfigError(f"{where}[{i}].id: must be a non-empty name")
        if ident in ids[:i]:
            raise ConfigError(f"{where}[{i}].id: {ident!r} is used twice")
    return ids


def _key_expr_problem(expr: str) -> str | None:
    """Why `expr` is not a Zenoh key expression as the access list takes them, or None: `/`-separated
    non-empty chunks, `*` and `**` only as whole chunks, no `#`, `?` or `$` (the loop's core reaches this
    module, so Zenoh's own parser is not imported here)."""
    if not expr:
        return "must be a non-empty key expression"
    chunks = expr.split("/")
    if "" in chunks:
        return f"{expr!r}: empty chunks, leading and trailing '/' are not allowed"
    for chunk in chunks:
        if any(c in chunk for c in "#?$") or any(c.isspace() for c in chunk):
            return f"{expr!r}: '#', '?', '$' and spaces are not allowed"
        if "*" in chunk and chunk not in ("*", "**"):
            return f"{expr!r}: '*' and '**' must be whole chunks (a/*/b, a/**)"
    return None


MAVLINK_URL_FORMS = ("udpout:HOST:PORT (send to HOST)", "udpin:HOST:PORT (listen; answer whoever sent last)",
                     "tcp:HOST:PORT (connect)", "tcpin:HOST:PORT (listen)", "a serial device path such as /dev/ttyACM0")
_NETWORK_SCHEMES = ("udpout", "udpin", "tcp", "tcpin")


def parse_network_url(url: str) -> tuple[str, str, int] | None:
    """`scheme:HOST:PORT` or the URL form `scheme://HOST:PORT` (as mavsdk and `gcs.cli` write it) with one of
    the network schemes -> (scheme, host, port); None for anything else."""
    scheme, colon, rest = url.partition(":")
    if not colon or scheme not in _NETWORK_SCHEMES:
        return None
    if rest.startswith("//"):
        rest = rest[2:]
    parts = rest.split(":")
    if len(parts) != 2:
        return None
    host, port = parts
    if not host or "/" in host or any(c.isspace() for c in host):
        return None
    if not port.isdigit() or not 0 < int(port) < 65536:
        return None
    return scheme, host, int(port)


def normalise_mavlink_url(url: str) -> str:
    """A network link in pymavlink's form `scheme:HOST:PORT` (`udpout://HOST:PORT` -> `udpout:HOST:PORT`);
    anything else (a serial device, a malformed URL) unchanged."""
    parsed = parse_network_url(url)
    if parsed is None:
        return url
    scheme, host, port = parsed
    return f"{scheme}:{host}:{port}"


def mavlink_url_problem(url: str) -> str | None:
    """Why `url` is not one of the MAVLink link forms the service accepts (MAVLINK_URL_FORMS), or None."""
    if url.startswith("/") and ":" not in url:
        return None  # a serial device; whether it exists is checked when the link opens
    if parse_network_url(url) is not None:
        return None
    return (f"{url!r} is not a MAVLink link; accepted forms: {'; '.join(MAVLINK_URL_FORMS)} "
            "(each network form also as scheme://HOST:PORT)")


def _build(cls: type, raw: object, path: str) -> Any:
    """Instantiate dataclass `cls` from a mapping, recursively, checking keys, types and ranges."""
    where = path or "config"
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{where}: must be a mapping, got {type(raw).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(map(str, raw)) - set(fields))
    if unknown:
        # an empty key, or one with spaces or dots, is quoted: the path must show which key it is
        name = unknown[0] if unknown[0].isidentifier() else repr(unknown[0])
        raise ConfigError(f"{_join(path, name)}: unknown key (known: {', '.join(fields)})")
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for name, f in fields.items():
        if name not in raw:
            continue
        key_path = _join(path, name)
        value = _coerce(hints[name], raw[name], key_path)
        for check in f.metadata.get("checks", ()):
            problem = check(value)
            if problem:
                raise ConfigError(f"{key_path}: {problem}")
        values[name] = value
    built = cls(**values)
    # defaults must pass their own checks too (guards against a wrong default in this file)
    for name, f in fields.items():
        for check in f.metadata.get("checks", ()):
            problem = check(getattr(built, name))
            if problem:
                raise ConfigError(f"{_join(path, name)}: {problem}")
    return built


def _coerce(hint: Any, value: object, key_path: str) -> Any:
    """Check `value` against type `hint`; ints are accepted for floats, nothing else is converted."""
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, key_path)
    if origin is Literal:
        choices = typing.get_args(hint)
        # By type as well as value: 1 == True, but a 1 where true or "auto" is meant is a mistake to name.
        if not any(type(value) is type(choice) and value == choice for choice in choices):
            shown = ", ".join(str(choice).lower() if isinstance(choice, bool) else str(choice) for choice in choices)
            raise ConfigError(f"{key_path}: must be one of {shown}, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key_path}: must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key_path}: must be an integer, got {_shown(value)}")
        if not INT_MIN <= value <= INT_MAX:  # the values go to C (OpenCV threads, sockets, struct fields)
            raise ConfigError(f"{key_path}: must be within a 32-bit integer's range, got {_shown(value)}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key_path}: must be a number, got {_shown(value)}")
        try:
            number = float(value)  # an integer beyond the float range (YAML reads 1000...0 as an int) overflows
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            raise ConfigError(f"{key_path}: must be finite, got {_shown(value)}")
        return number
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key_path}: must be a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key_path}: must be a list, got {value!r}")
        item = typing.get_args(hint)[0]
        return tuple(_coerce(item, v, f"{key_path}[{i}]") for i, v in enumerate(value))
    if origin in (collections.abc.Mapping, dict):
        if value is None:
            return types.MappingProxyType({})
        if not isinstance(value, Mapping):
            raise ConfigError(f"{key_path}: must be a mapping, got {value!r}")
        return types.MappingProxyType(dict(value))
    raise TypeError(f"{key_path}: unsupported config type {hint!r}")


INT_MIN, INT_MAX = -2**31, 2**31 - 1  # integer settings: the signed 32-bit range


def _shown(value: object, limit: int = 80) -> str:
    """repr(value) cut to `limit` characters (a fuzzed file may hold a 400-digit number or a 10 kB string)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name
