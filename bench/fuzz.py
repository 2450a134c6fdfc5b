"""Fuzzing the daemon's inputs: its MAVLink port, its Zenoh frame and status keys, and config.yaml.

    python -m bench.fuzz mavlink --inputs 100000 --seed 1 [--rate 2500] [--json out/fuzz/mavlink.json]
    python -m bench.fuzz zenoh --inputs 20000 --seed 1 [--json out/fuzz/zenoh.json]
    python -m bench.fuzz config --inputs 5000 --seed 1 [--processes 12] [--json out/fuzz/config.json]

Every input comes from a seeded `random.Random` (the same seed gives the same inputs), every run is bounded
(`--inputs`, and a wall-clock cap `--max-s`), and the counts are printed and written as JSON.

MAVLink: the daemon (`python -m service`, a process) on a looping synthetic clip paced like a camera, its link
`udpout` to this benchmark, which plays the autopilot (heartbeats) and a ground station (a selection, probes)
and sends the fuzz to the daemon's port from the same socket. Inputs (one UDP datagram each): every message the
daemon handles with random field values (COMMAND_LONG / COMMAND_INT with every command id it decides on and
random others, HEARTBEAT, GLOBAL_POSITION_INT, ATTITUDE, GIMBAL_DEVICE_ATTITUDE_STATUS, GIMBAL_MANAGER_STATUS),
in MAVLink 2 and MAVLink 1 framing; random messages of the rest of the dialect and the ones the link's parser
keeps by name (PARAM_VALUE, NAMED_VALUE_*, DEBUG_VECT); signed packets (random signature bytes, or signed with
another key); truncated packets, bad CRCs, wrong length bytes, random bytes, several packets in one datagram.
Measured: crashes (the process exits), hangs (a probe COMMAND_LONG every 0.5 s answered, the status query
answered during the fuzz, a valid command answered after it), tracebacks and handler failures in the log,
resident memory (before, sampled during, after) and the tracked frame rate against a run without fuzz in the
same benchmark (telemetry samples per second on `<prefix>/track`).

Zenoh: the daemon with `source.kind: zenoh`; this benchmark publishes the camera (a clip at `--fps`) and,
interleaved on `<prefix>/camera/frame`, malformed payloads (short, bad magic, unknown pixel formats, sizes that
do not match, corrupt and lying JPEGs, zero / huge dimensions, huge payloads, valid frames of odd sizes), and
random queries on `<prefix>/status` (selectors with random parameters, payloads, encodings, wildcards). Same
measurements.

Config: random mutations of the project's config.yaml (values of the wrong type or out of range, unknown keys,
deleted sections, deep nesting, huge numbers, NaN / inf strings and YAML floats, empty / binary / truncated
files, recursive anchors), each loaded in process by service.config.load_config (and the tracker's parameters
by jsar.create, as the daemon does at start): a ConfigError naming a key of the file or of the schema (or the
file itself), or a clean load; anything else (a traceback) is a failure. `--processes N` also starts the
daemon on N of them: exit 2 with `configuration error: KEY`, or a clean start (event=started) and stop.
"""
from __future__ import annotations

import argparse
import ast
import copy
import json
import math
import os
import random
import re
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from pymavlink.dialects.v20 import all as dialect  # noqa: E402

from sim.ports import free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MAVLINK20": "1"}
AUTOPILOT = (1, 1)  # the system the daemon is configured for (mavlink.system_id), its autopilot component
CAMERA = (1, 100)
GCS = (255, 190)
NAN, INF = float("nan"), float("inf")

# --- MAVLink inputs (pure: a seeded generator of datagrams) ----------------------------------------------------
# The commands service.mavlink.commands.decide acts on (every other id is UNSUPPORTED); tests check the list.
HANDLED_COMMANDS = (
    dialect.MAV_CMD_CAMERA_TRACK_POINT, dialect.MAV_CMD_CAMERA_TRACK_RECTANGLE, dialect.MAV_CMD_CAMERA_STOP_TRACKING,
    dialect.MAV_CMD_SET_MESSAGE_INTERVAL, dialect.MAV_CMD_REQUEST_MESSAGE, dialect.MAV_CMD_REQUEST_CAMERA_INFORMATION,
    dialect.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, dialect.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS,
)
# The messages the daemon reads besides commands (service.mavlink.autopilot.observe)
HANDLED_MESSAGES = ("HEARTBEAT", "GLOBAL_POSITION_INT", "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS",
                    "GIMBAL_MANAGER_STATUS")
# Messages pymavlink's connection keeps per source by a name or id inside them (mavutil.post_message)
NAMED_MESSAGES = ("PARAM_VALUE", "NAMED_VALUE_FLOAT", "NAMED_VALUE_INT", "DEBUG_VECT", "NAMED_VALUE_STRING")
SPECIAL_FLOATS = (NAN, INF, -INF, 0.0, -0.0, 1.0, -1.0, 0.5, 1e-45, 1e-38, 3.4e38, -3.4e38, 1e9, 100.0, 0.999999,
                  1.000001)
# message ids a command's parameter 1 may name (REQUEST_MESSAGE / SET_MESSAGE_INTERVAL)
MESSAGE_IDS = (259, 269, 270, 275, 276, 0, 33, 65535, 16777215)
INT_RANGES = {"int8_t": (-2**7, 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-2**15, 2**15 - 1),
              "uint16_t": (0, 2**16 - 1), "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1),
              "int64_t": (-2**63, 2**63 - 1), "uint64_t": (0, 2**64 - 1), "uint8_t_mavlink_version": (0, 255)}
MESSAGE_CLASSES = {cls.msgname: cls for cls in dialect.mavlink_map.values()}
V1_MESSAGES = tuple(sorted(name for name, cls in MESSAGE_CLASSES.items() if cls.id < 256))

# kind of input -> weight (share of the inputs)
MAVLINK_KINDS = {"handled_v2": 30, "handled_v1": 10, "command_v2_valid_shape": 8, "other_message": 6,
                 "named_message": 6, "signed_random": 4, "signed_other_key": 3, "truncated": 9, "bad_crc": 8,
                 "wrong_length": 6, "random_bytes": 5, "bit_flips": 3, "several_packets": 2}


def random_float(rng: random.Random) -> float:
    """A float32-representable value: special values half the time, else uniform in a few ranges."""
    roll = rng.random()
    if roll < 0.45:
        return rng.choice(SPECIAL_FLOATS)
    if roll < 0.75:
        return rng.random()  # normalised image coordinates: where the commands' checks sit
    return rng.uniform(-1e6, 1e6) if roll < 0.9 else rng.uniform(-3e38, 3e38)


def random_int(rng: random.Random, kind: str) -> int:
    """An integer of a MAVLink integer type: its bounds, 0, 1 or uniform in range."""
    low, high = INT_RANGES[kind]
    roll = rng.random()
    if roll < 0.3:
        return rng.choice((low, high, 0, 1, min(high, 255)))
    return rng.randint(low, high)


def random_field(rng: random.Random, kind: str, length: int) -> Any:
    """A random value for one field (`kind` as pymavlink's fieldtypes; `length` > 0: an array)."""
    if kind == "char":  # a char array (bytes up to its length) or one char
        size = rng.randint(0, length) if length else 1
        return bytes(rng.choice((rng.randint(0, 255), rng.randint(32, 126))) for _ in range(size))
    one: Callable[[], Any] = ((lambda: random_float(rng)) if kind in ("float", "double")
                              else (lambda: random_int(rng, kind)))
    return [one() for _ in range(length)] if length else one()


def random_message(rng: random.Random, name: str) -> object:
    """A pymavlink message of type `name` with every field random."""
    cls = MESSAGE_CLASSES[name]
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    values = [random_field(rng, kind, lengths[fname]) for fname, kind in zip(cls.fieldnames, cls.fieldtypes)]
    return cls(*values)


def random_command(rng: random.Random, kind: str) -> object:
    """COMMAND_LONG or COMMAND_INT: a handled command id (mostly) or any id, to the camera (mostly), with random
    parameters; parameter 1 names a message id at times (REQUEST_MESSAGE / SET_MESSAGE_INTERVAL)."""
    command = rng.choice(HANDLED_COMMANDS) if rng.random() < 0.85 else random_int(rng, "uint16_t")
    target = rng.choice((CAMERA, CAMERA, (0, 0), (1, 0), (0, 100), (1, 1), (rng.randint(0, 255), rng.randint(0, 255))))
    params = [random_float(rng) for _ in range(7)]
    if rng.random() < 0.5:
        params[0] = float(rng.choice(MESSAGE_IDS))
    if rng.random() < 0.3:
        params[1] = rng.choice((-1.0, 0.0, 1000.0, 9999.0, 1e6, 1.0))
    if kind == "COMMAND_LONG":
        return dialect.MAVLink_command_long_message(*target, command, rng.randint(0, 255), *params)
    x, y = (random_int(rng, "int32_t") for _ in range(2))
    return dialect.MAVLink_command_int_message(*target, rng.randint(0, 255), command, rng.randint(0, 255),
                                               rng.randint(0, 255), *params[:4], x, y, params[6])


def packer(rng: random.Random, source: tuple[int, int] | None = None, key: bytes | None = None) -> object:
    """A pymavlink MAVLink encoder sending as `source` (random when None), signing with `key` when given."""
    system, component = source or rng.choice((AUTOPILOT, GCS, CAMERA, (rng.randint(0, 255), rng.randint(0, 255))))
    mav = dialect.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.seq = rng.randint(0, 255)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = rng.randint(0, 255)
        mav.signing.timestamp = rng.choice((0, 1, 2**48 - 1, rng.randint(0, 2**48 - 1)))
    return mav


def handled_message(rng: random.Random) -> object:
    """One of the messages the daemon handles, fields random; commands half the time."""
    if rng.random() < 0.5:
        return random_command(rng, rng.choice(("COMMAND_LONG", "COMMAND_INT")))
    return random_message(rng, rng.choice(HANDLED_MESSAGES))


def encode(rng: random.Random, msg: object, v1: bool = False, source: tuple[int, int] | None = None,
           key: bytes | None = None) -> bytes:
    """The message as a MAVLink 2 (or 1) packet from `source` (the autopilot's system a third of the time)."""
    if source is None and rng.random() < 0.35:
        source = AUTOPILOT
    return bytes(msg.pack(packer(rng, source, key), force_mavlink1=v1))


def valid_packet(rng: random.Random) -> bytes:
    """A well-formed packet of a handled message (MAVLink 1 or 2) to mutate."""
    if rng.random() < 0.3:
        return mavlink_input(rng, "handled_v1")
    return encode(rng, handled_message(rng))


def with_signed_flag(rng: random.Random, packet: bytes) -> bytes:
    """A MAVLink 2 packet marked signed (incompat flag 0x01, CRC recomputed) with 13 random signature bytes."""
    data = bytearray(packet)
    data[2] |= dialect.MAVLINK_IFLAG_SIGNED
    msg_id = data[7] | data[8] << 8 | data[9] << 16
    crc = dialect.x25crc(bytes(data[1:-2]))
    crc.accumulate(struct.pack("B", dialect.mavlink_map[msg_id].crc_extra))
    data[-2:] = struct.pack("<H", crc.crc)
    return bytes(data) + bytes(rng.randint(0, 255) for _ in range(13))


def mavlink_input(rng: random.Random, kind: str) -> bytes:
    """One fuzz datagram of the given kind (MAVLINK_KINDS)."""
    if kind == "handled_v2":
        return encode(rng, handled_message(rng))
    if kind == "handled_v1":
        msg = random_command(rng, "COMMAND_LONG") if rng.random() < 0.5 else random_message(
            rng, rng.choice(HANDLED_MESSAGES[:3]))
        return encode(rng, msg, v1=True)
    if kind == "command_v2_valid_shape":  # parameters in range more often: reaches the accepted paths
        msg = random_command(rng, rng.choice(("COMMAND_LONG", "COMMAND_INT")))
        for name in ("param1", "param2", "param3", "param4"):
            if rng.random() < 0.8:
                setattr(msg, name, rng.random())
        return encode(rng, msg, source=GCS)
    if kind == "other_message":
        return encode(rng, random_message(rng, rng.choice(sorted(MESSAGE_CLASSES))))
    if kind == "named_message":
        return encode(rng, random_message(rng, rng.choice(NAMED_MESSAGES)))
    if kind == "signed_random":
        return with_signed_flag(rng, encode(rng, handled_message(rng)))
    if kind == "signed_other_key":
        return encode(rng, handled_message(rng), key=bytes(rng.randint(0, 255) for _ in range(32)))
    if kind == "truncated":
        packet = valid_packet(rng)
        return packet[:rng.randint(1, len(packet) - 1)]
    if kind == "bad_crc":
        packet = bytearray(valid_packet(rng))
        at = rng.randint(1, len(packet) - 1)
        packet[at] ^= rng.randint(1, 255)
        return bytes(packet)
    if kind == "wrong_length":
        packet = bytearray(valid_packet(rng))
        packet[1] = (packet[1] + rng.randint(1, 255)) % 256
        return bytes(packet)
    if kind == "random_bytes":
        data = bytes(rng.randint(0, 255) for _ in range(rng.choice((0, 1, 2, 10, rng.randint(0, 300), 2048))))
        return (bytes([rng.choice((0xFD, 0xFE))]) + data) if rng.random() < 0.5 else data
    if kind == "bit_flips":
        packet = bytearray(valid_packet(rng))
        for _ in range(rng.randint(1, 8)):
            at = rng.randrange(len(packet))
            packet[at] ^= 1 << rng.randrange(8)
        return bytes(packet)
    if kind == "several_packets":
        parts = [mavlink_input(rng, rng.choice(("handled_v2", "handled_v1", "truncated", "bad_crc", "random_bytes")))
                 for _ in range(rng.randint(2, 5))]
        return b"".join(parts)
    raise ValueError(f"unknown MAVLink input kind {kind!r}")


def mavlink_inputs(seed: int, count: int) -> Iterator[tuple[str, bytes]]:
    """`count` (kind, datagram) pairs from `seed`: the same seed, the same inputs."""
    rng = random.Random(seed)
    kinds, weights = zip(*MAVLINK_KINDS.items())
    for _ in range(count):
        kind = rng.choices(kinds, weights)[0]
        yield kind, mavlink_input(rng, kind)


# --- Zenoh inputs (pure) -------------------------------------------------------------------------------------
ZENOH_FRAME_KINDS = {"short": 8, "bad_magic": 8, "unknown_format": 8, "size_mismatch": 12, "zero_size": 5,
                     "huge_dimensions": 8, "corrupt_jpeg": 10, "lying_jpeg": 8, "jpeg_bomb": 4, "random_bytes": 10,
                     "huge_payload": 2, "nan_timestamp": 5, "odd_size_frame": 7, "truncated_frame": 5}


def _header(fmt: bytes, width: int, height: int, frame_id: int, timestamp: float, magic: bytes = b"JFR1") -> bytes:
    from service.sources.zenoh_wire import HEADER

    return HEADER.pack(magic, fmt, width, height, frame_id, timestamp)


def tiny_jpeg(rng: random.Random, width: int = 16, height: int = 16) -> bytes:
    """A small valid JPEG of random pixels."""
    import cv2

    image = np.random.default_rng(rng.randint(0, 2**31)).integers(0, 255, (height, width, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", image)
    assert ok
    return buf.tobytes()


def jpeg_claiming(jpeg: bytes, width: int, height: int) -> bytes:
    """The JPEG with its frame header (SOF0) rewritten to say width x height (the data stays small)."""
    data = bytearray(jpeg)
    at = data.find(b"\xff\xc0")
    if at < 0:
        raise ValueError("no SOF0 marker")
    data[at + 5:at + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def zenoh_frame_input(rng: random.Random, kind: str, frame_id: int) -> bytes:
    """One malformed (or odd but valid) payload for `<prefix>/camera/frame`."""
    now = time.time()
    if kind == "short":
        return bytes(rng.randint(0, 255) for _ in range(rng.randint(0, 31)))
    if kind == "bad_magic":
        return _header(b"BGR3", 4, 4, frame_id, now, magic=bytes(rng.randint(0, 255) for _ in range(4))) + bytes(48)
    if kind == "unknown_format":
        return _header(bytes(rng.randint(0, 255) for _ in range(4)), 4, 4, frame_id, now) + bytes(48)
    if kind == "size_mismatch":
        fmt = rng.choice((b"BGR3", b"GRAY"))
        width, height = rng.randint(1, 640), rng.randint(1, 480)
        size = width * height * (3 if fmt == b"BGR3" else 1) + rng.choice((-1, 1, -width, 17))
        return _header(fmt, width, height, frame_id, now) + bytes(max(size, 0))
    if kind == "zero_size":
        return _header(rng.choice((b"BGR3", b"GRAY", b"JPEG")), rng.choice((0, 5)), rng.choice((0, 0, 5)), frame_id,
                       now) + bytes(16)
    if kind == "huge_dimensions":
        width, height = rng.choice(((2**32 - 1, 2**32 - 1), (65535, 65535), (2**31, 1), (1, 2**32 - 1)))
        return _header(rng.choice((b"BGR3", b"GRAY", b"JPEG")), width, height, frame_id, now) + bytes(64)
    if kind == "corrupt_jpeg":
        jpeg = bytearray(tiny_jpeg(rng))
        for _ in range(rng.randint(1, 20)):
            jpeg[rng.randrange(len(jpeg))] = rng.randint(0, 255)
        return _header(b"JPEG", 16, 16, frame_id, now) + bytes(jpeg[:rng.randint(2, len(jpeg))])
    if kind == "lying_jpeg":  # a valid JPEG of another size than the header's
        return _header(b"JPEG", rng.randint(1, 4000), rng.randint(1, 4000), frame_id, now) + tiny_jpeg(rng)
    if kind == "jpeg_bomb":  # a few hundred bytes whose JPEG header claims a huge image (and the wire header agrees)
        width, height = rng.choice(((60000, 60000), (30000, 30000), (65500, 16), (16384, 16384)))
        return _header(b"JPEG", width, height, frame_id, now) + jpeg_claiming(tiny_jpeg(rng), width, height)
    if kind == "random_bytes":
        return bytes(rng.randint(0, 255) for _ in range(rng.randint(0, 4096)))
    if kind == "huge_payload":  # a plausible header then far more data than it says
        return _header(b"GRAY", 8, 8, frame_id, now) + bytes(rng.choice((8 * 1024 * 1024, 24 * 1024 * 1024)))
    if kind == "nan_timestamp":
        return _header(b"GRAY", 8, 8, frame_id, rng.choice((NAN, INF, -INF))) + bytes(64)
    if kind == "odd_size_frame":  # valid frames the tracker cannot use as they are: tiny, thin, large
        width, height = rng.choice(((1, 1), (2, 2), (1, 480), (640, 1), (7, 5), (1920, 1080)))
        fmt = rng.choice((b"BGR3", b"GRAY"))
        return _header(fmt, width, height, frame_id, now) + bytes(width * height * (3 if fmt == b"BGR3" else 1))
    if kind == "truncated_frame":
        return _header(b"BGR3", 320, 240, frame_id, now) + bytes(rng.randint(0, 320 * 240 * 3 - 1))
    raise ValueError(f"unknown Zenoh frame input kind {kind!r}")


def zenoh_query_input(rng: random.Random, prefix: str) -> tuple[str, str, bytes | None, str | None]:
    """A random query: (key expression, parameters, payload or None, encoding or None)."""
    key = rng.choice((f"{prefix}/status", f"{prefix}/status", f"{prefix}/*", f"{prefix}/**", "**",
                      f"{prefix}/status/**", f"{prefix}/$*", f"{prefix}/camera/frame", f"{prefix}/track"))
    alphabet = "abc=;&%?*#/\\\"' \t\x00\u00e9\u4e2d_-0123456789"
    params = "".join(rng.choice(alphabet) for _ in range(rng.choice((0, 1, 8, 64, 1024))))
    # a query is not fragmented: the payloads stay well below a 64 kB batch
    payload = None if rng.random() < 0.4 else bytes(rng.randint(0, 255) for _ in range(rng.choice((0, 5, 200, 8000))))
    # an encoding schema over 255 bytes panics the sender in zenoh-python 1.10.2 (never reaching the daemon)
    encoding = rng.choice((None, "application/json", "text/plain", "zenoh/bytes", "x/" + "z" * rng.randint(0, 200)))
    return key, params, payload, encoding


# --- the daemon as a process ---------------------------------------------------------------------------------
def scene(size: tuple[int, int], centre: tuple[float, float], side: int = 40, seed: int = 7) -> np.ndarray:
    """A textured background (fixed seed) with a bright checkered square at `centre` (pixels), BGR uint8."""
    import cv2

    width, height = size
    rng = np.random.default_rng(seed)
    image = cv2.resize(rng.integers(0, 120, (height // 8 + 1, width // 8 + 1, 3), dtype=np.uint8), (width, height),
                       interpolation=cv2.INTER_NEAREST)
    x0, y0 = int(centre[0] - side / 2), int(centre[1] - side / 2)
    patch = np.full((side, side, 3), 250, np.uint8)
    patch[::8, :, 1] = 30
    patch[:, ::8, 2] = 30
    image[y0:y0 + side, x0:x0 + side] = patch
    return image


CLIP_SIZE = (320, 240)
CLIP_FRAMES = 60


def clip_frame(i: int) -> np.ndarray:
    """Frame i of the synthetic clip: the square drifts left and right around the centre (period CLIP_FRAMES)."""
    x = 160 + 30 * math.sin(2 * math.pi * i / CLIP_FRAMES)
    return scene(CLIP_SIZE, (x, 120))


def write_clip(folder: Path) -> Path:
    """The clip as an image folder (PNG) for the file source."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for i in range(CLIP_FRAMES):
        cv2.imwrite(str(folder / f"{i:04d}.png"), clip_frame(i))
    return folder


SELECTION = (0.36, 0.41, 0.64, 0.59)  # TRACK_RECTANGLE around the square, normalised


def daemon_config(mavlink_port: int, zenoh_port: int, source: dict, tracker: str, fps: float,
                  key_file: Path | None = None) -> dict:
    """The daemon under fuzz: the given source, Zenoh on loopback only (prefix `fuzz`), no preview; MAVLink
    signing with unsigned packets refused when key_file is given."""
    return {"source": {"retry_initial_s": 0.05, "retry_max_s": 0.5, "fps": fps, **source},
            "tracker": {"name": tracker, **({} if tracker.startswith("jsar") else {"range_size_band": 0})},
            "mavlink": {"url": f"udpout:127.0.0.1:{mavlink_port}", "system_id": AUTOPILOT[0],
                        **({"signing": {"key_file": str(key_file)}} if key_file is not None else {})},
            "gimbal": {"backend": "ardupilot"},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "prefix": "fuzz"},
            "video": {"preview": {"enabled": False}},
            "logging": {"level": "INFO"}}


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process (MB, VmRSS), None once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def udp_drops(port: int) -> int | None:
    """Datagrams the kernel dropped for the UDP socket bound to `port` (a full receive buffer), from /proc/net/udp."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    for line in lines:
        parts = line.split()
        if int(parts[1].split(":")[1], 16) == port:
            return int(parts[-1])
    return None


class Daemon:
    """`python -m service --config FILE` with its log in a file; stop() by its pid (SIGTERM, then SIGKILL)."""

    def __init__(self, workdir: Path, config: dict) -> None:
        self.config_file = workdir / "config.yaml"
        self.config_file.write_text(yaml.safe_dump(config))
        self.log_file = workdir / "daemon.log"
        self._log = open(self.log_file, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(self.config_file)], cwd=REPO,
                                     env={**os.environ, **ONE_THREAD_ENV}, stdout=self._log, stderr=subprocess.STDOUT)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> int | None:
        """SIGTERM and wait; the exit code (None if it had to be killed)."""
        code: int | None = self.proc.poll()
        if code is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                code = self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                code = None
        self._log.close()
        return code

    def log(self) -> str:
        return self.log_file.read_text(errors="replace")


LOG_FAILURES = ("Traceback", "event=message_handling_failed", "event=step_failed", "event=status_query_failed",
                "event=loop_crashed", "event=capture_failed", "event=telemetry_failed")


def log_failures(text: str) -> dict[str, int]:
    """Counts of the log lines that mean an input was not handled as designed (LOG_FAILURES)."""
    return {marker: text.count(marker) for marker in LOG_FAILURES if marker in text}


def failure_lines(text: str, limit: int = 6) -> list[str]:
    """The first log lines holding a LOG_FAILURES marker (each with its traceback, cut to 3000 characters)."""
    lines = [line for line in text.splitlines() if any(marker in line for marker in LOG_FAILURES[1:])]
    return [line[:3000] for line in lines[:limit]]


def zenoh_session(port: int) -> Any:
    """A Zenoh peer connected to the daemon's listen endpoint only (no multicast scouting)."""
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(config)


def query_status(session: Any, timeout_s: float = 2.0) -> dict | None:
    """The daemon's status answer on fuzz/status, None when none came within timeout_s."""
    replies = list(session.get("fuzz/status", timeout=timeout_s))
    for reply in replies:
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_string())
    return None


class TrackCounter:
    """Telemetry samples on fuzz/track: arrival times, frame ids and end-to-end latency (ms)."""

    def __init__(self, session: Any) -> None:
        self._lock = threading.Lock()
        self.samples: list[tuple[float, int, float, str]] = []  # (arrival monotonic s, frame id, total ms, state)
        self._sub = session.declare_subscriber("fuzz/track", self._on)

    def _on(self, sample: Any) -> None:
        try:
            data = json.loads(sample.payload.to_string())
            row = (time.monotonic(), int(data["frame_id"]), float(data["latency_ms"]["total"]), str(data["state"]))
        except (ValueError, KeyError, TypeError):
            return
        with self._lock:
            self.samples.append(row)

    def window(self, start: float, end: float, max_frame_id: int | None = None) -> dict[str, Any]:
        """Frames per second, tracked share and latency p50 / p99 between two monotonic times."""
        with self._lock:
            rows = [r for r in self.samples if start <= r[0] < end and (max_frame_id is None or r[1] <= max_frame_id)]
        latencies = sorted(r[2] for r in rows)
        pick = (lambda q: round(latencies[min(len(latencies) - 1, int(q * len(latencies)))], 2)) if latencies else (
            lambda q: None)
        return {"frames": len(rows), "fps": round(len(rows) / max(end - start, 1e-9), 2),
                "tracking_share": round(sum(r[3] in ("tracking", "recovered") for r in rows) / max(len(rows), 1), 3),
                "latency_ms_p50": pick(0.5), "latency_ms_p99": pick(0.99)}

    def close(self) -> None:
        self._sub.undeclare()


class MavlinkPeer:
    """The benchmark's one UDP socket at the daemon's udpout destination: the autopilot's heartbeats (10 Hz),
    the ground station's commands and the fuzz all leave from it, and the daemon's packets arrive on it."""

    def __init__(self, port: int, key: bytes | None = None) -> None:
        """key: sign the autopilot's and the ground station's packets with this 32-byte secret (link id 0)."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.daemon_address: tuple[str, int] | None = None
        self.autopilot = dialect.MAVLink(None, srcSystem=AUTOPILOT[0], srcComponent=AUTOPILOT[1])
        self.gcs = dialect.MAVLink(None, srcSystem=GCS[0], srcComponent=GCS[1])
        for mav in (self.autopilot, self.gcs) if key is not None else ():
            mav.signing.secret_key = key
            mav.signing.sign_outgoing = True
            mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)  # 10-us units since 2015
        self.parser = dialect.MAVLink(None)
        self.parser.robust_parsing = True
        self._cond = threading.Condition()
        self.acks: list[tuple[float, int, int]] = []  # (arrival, command, result)
        self.received = 0
        self._stop = threading.Event()
        self._send_lock = threading.Lock()
        self._threads = [threading.Thread(target=self._receive, daemon=True),
                         threading.Thread(target=self._beat, daemon=True)]
        for thread in self._threads:
            thread.start()

    def wait_daemon(self, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.daemon_address is not None, timeout_s)

    def send_raw(self, data: bytes) -> None:
        if self.daemon_address is None:
            return
        with self._send_lock:
            self.sock.sendto(data, self.daemon_address)

    def command(self, command: int, params: list[float]) -> float:
        """Send a COMMAND_LONG from the ground station to the camera; returns when it was sent (monotonic)."""
        msg = self.gcs.command_long_encode(CAMERA[0], CAMERA[1], command, 0, *params)
        with self._send_lock:
            data = msg.pack(self.gcs)
        sent = time.monotonic()
        self.send_raw(data)
        return sent

    def wait_ack(self, command: int, after: float, timeout_s: float) -> tuple[float, int] | None:
        """The first COMMAND_ACK for `command` that arrived after `after`: (arrival, result), None on timeout."""
        def found() -> tuple[float, int] | None:
            return next(((t, r) for t, c, r in self.acks if c == command and t >= after), None)
        with self._cond:
            self._cond.wait_for(lambda: found() is not None, timeout_s)
            return found()

    def request(self, command: int, params: list[float], attempts: int, timeout_s: float) -> tuple[int, float, int] | None:
        """A command answered: (attempt it took, round trip s, result) or None after `attempts`."""
        for attempt in range(1, attempts + 1):
            sent = self.command(command, params)
            ack = self.wait_ack(command, sent, timeout_s)
            if ack is not None:
                return attempt, ack[0] - sent, ack[1]
        return None

    def _beat(self) -> None:
        while not self._stop.wait(0.1):
            with self._send_lock:
                data = self.autopilot.heartbeat_encode(2, 3, 0x81, 0, 4).pack(self.autopilot)
            self.send_raw(data)

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                data, address = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            except OSError:
                return
            try:
                messages = self.parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - the parser's own errors on odd bytes
                messages = []
            with self._cond:
                self.received += 1
                if self.daemon_address is None:
                    self.daemon_address = address
                for msg in messages:
                    if msg.get_type() == "COMMAND_ACK" and msg.get_srcComponent() == CAMERA[1]:
                        self.acks.append((time.monotonic(), msg.command, msg.result))
                if len(self.acks) > 10000:
                    del self.acks[:5000]
                self._cond.notify_all()

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(1.0)
        self.sock.close()


@dataclass
class Probes:
    """A valid command every `period_s` while the fuzz runs, and the status query: answered or not, latency."""

    sent: int = 0
    answered: int = 0
    round_trips_s: list[float] = field(default_factory=list)
    status_asked: int = 0
    status_answered: int = 0
    status_s: list[float] = field(default_factory=list)
    rss_mb: list[tuple[float, float]] = field(default_factory=list)  # (s since fuzz start, MB)

    def summary(self) -> dict[str, Any]:
        def q(values: list[float], p: float) -> float | None:
            ordered = sorted(values)
            return round(ordered[min(len(ordered) - 1, int(p * len(ordered)))] * 1000, 1) if ordered else None
        return {"selection_probes": self.sent, "selection_probes_answered": self.answered,
                "selection_probe_ms_p50": q(self.round_trips_s, 0.5),
                "selection_probe_ms_max": q(self.round_trips_s, 1.0),
                "status_queries": self.status_asked, "status_answered": self.status_answered,
                "status_ms_p50": q(self.status_s, 0.5), "status_ms_max": q(self.status_s, 1.0)}


def watch(stop: threading.Event, daemon: Daemon, peer: MavlinkPeer | None, session: Any, probes: Probes,
          started: float, period_s: float = 0.5) -> None:
    """While the fuzz runs: one probe command, one status query and one memory sample each period. The probe
    selects the clip's target again (TRACK_RECTANGLE): the fuzz's own accepted STOP_TRACKING commands would
    otherwise leave the daemon idle, and an idle loop's frame rate says nothing about tracking's."""
    while not stop.wait(period_s):
        if not daemon.alive():
            return
        mb = rss_mb(daemon.proc.pid)
        if mb is not None:
            probes.rss_mb.append((round(time.monotonic() - started, 2), round(mb, 1)))
        if peer is not None:
            probes.sent += 1
            sent = peer.command(dialect.MAV_CMD_CAMERA_TRACK_RECTANGLE, [*SELECTION, 0, 0, 0])
            ack = peer.wait_ack(dialect.MAV_CMD_CAMERA_TRACK_RECTANGLE, sent, 1.0)
            if ack is not None:
                probes.answered += 1
                probes.round_trips_s.append(ack[0] - sent)
        probes.status_asked += 1
        asked = time.monotonic()
        if query_status(session, timeout_s=2.0) is not None:
            probes.status_answered += 1
            probes.status_s.append(time.monotonic() - asked)


def wait_for(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.2) -> bool:
    """Poll `predicate` (a status query, a count: no event to wait on across processes) until true or timeout."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return False


def select_target(peer: MavlinkPeer) -> bool:
    """TRACK_RECTANGLE around the clip's square, retried until ACCEPTED (the source may still be starting)."""
    for _ in range(20):
        answer = peer.request(dialect.MAV_CMD_CAMERA_TRACK_RECTANGLE, [*SELECTION, 0, 0, 0], attempts=3, timeout_s=1.0)
        if answer is not None and answer[2] == dialect.MAV_RESULT_ACCEPTED:
            return True
        time.sleep(0.5)
    return False


def memory_verdict(before: float | None, after: float | None, samples: list[tuple[float, float]]) -> dict[str, Any]:
    """Memory before / after and during (max); the slope over the second half of the samples (MB per minute)."""
    half = samples[len(samples) // 2:]
    slope = None
    if len(half) >= 4:
        t = np.array([s[0] for s in half])
        m = np.array([s[1] for s in half])
        slope = round(float(np.polyfit(t, m, 1)[0]) * 60, 2)
    return {"rss_mb_before": before, "rss_mb_after": after,
            "rss_mb_max_during": max((s[1] for s in samples), default=None),
            "rss_growth_mb": round(after - before, 1) if before is not None and after is not None else None,
            "rss_slope_mb_per_min_second_half": slope}


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def paced(items: Iterable[Any], rate: float, deadline: float, daemon: Daemon) -> Iterator[Any]:
    """`items` one every 1/rate seconds while the daemon lives, until `deadline` (time.monotonic() s)."""
    period, next_at = 1.0 / rate, time.monotonic()
    for item in items:
        if not daemon.alive() or time.monotonic() > deadline:
            return
        now = time.monotonic()
        if next_at > now:
            time.sleep(next_at - now)  # pacing the sender, not waiting for the daemon
        next_at += period
        yield item


class Probing:
    """The probes (see watch) on a thread from `started` (monotonic s) until stop()."""

    def __init__(self, daemon: Daemon, peer: MavlinkPeer, session: Any, started: float) -> None:
        self.probes = Probes()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=watch, args=(self._stop, daemon, peer, session, self.probes, started),
                                        daemon=True)
        self._thread.start()

    def stop(self, after_s: float = 0.0) -> Probes:
        """Stop probing `after_s` seconds from now; the probes."""
        self._stop.wait(after_s)
        self._stop.set()
        self._thread.join()
        return self.probes


def daemon_session(daemon: Daemon, peer: MavlinkPeer, zenoh_port: int) -> Any:
    """A Zenoh session on the daemon's port once the daemon's first packet reached the peer (within 90 s)."""
    if not wait_for(lambda: peer.daemon_address is not None or not daemon.alive(), 90.0) or not daemon.alive():
        raise RuntimeError(f"no packet from the daemon within 90 s; log:\n{daemon.log()[-3000:]}")
    return zenoh_session(zenoh_port)


def select_and_track(daemon: Daemon, peer: MavlinkPeer, track: TrackCounter) -> None:
    """Select the clip's target; wait (up to 20 s) until most of the last second's frames are tracked."""
    if not select_target(peer):
        raise RuntimeError(f"the selection was never accepted; log:\n{daemon.log()[-3000:]}")
    wait_for(lambda: track.window(time.monotonic() - 1.0, time.monotonic())["tracking_share"] > 0.5, 20.0)


def fuzz_outcome(daemon: Daemon, peer: MavlinkPeer, session: Any, track: TrackCounter, max_frame_id: int | None,
                 baseline: tuple[dict[str, Any], Probes], during: tuple[dict[str, Any], Probes],
                 rss_before: float | None) -> tuple[dict[str, Any], dict | None]:
    """After the fuzz: a valid command answered, the target selected and tracked again, memory once settled.
    The result's entries common to every target (baseline / during: the track window and the probes), and the
    daemon's last status (None when it died or no longer answers)."""
    alive = daemon.alive()
    command = peer.request(dialect.MAV_CMD_REQUEST_MESSAGE, [275, 0, 0, 0, 0, 0, 0], attempts=5,
                           timeout_s=1.0) if alive else None
    reselected = select_target(peer) if alive else False
    settle = time.monotonic()
    # let the last inputs' replies and any retried work finish (a camera keeps publishing) before the readings
    time.sleep(3.0)
    after = track.window(settle, time.monotonic(), max_frame_id=max_frame_id)
    rss_after = rss_mb(daemon.proc.pid)
    status = query_status(session, 3.0) if alive else None
    (base, base_probes), (fuzzed, probes) = baseline, during
    return {
        "crashes": 0 if alive else 1, "exit_code": None if alive else daemon.proc.returncode,
        "hangs": int(not (command is not None and status is not None)),
        "command_after_fuzz": (None if command is None else
                               {"attempt": command[0], "ms": round(command[1] * 1000, 1), "result": command[2]}),
        "reselected_after_fuzz": reselected,
        "baseline": {**base, **base_probes.summary()}, "during": {**fuzzed, **probes.summary()},
        "after": after,
        "frame_rate_ratio": round(fuzzed["fps"] / base["fps"], 3) if base["fps"] else None,
        "memory": memory_verdict(rss_before, rss_after, probes.rss_mb),
        "rss_samples": probes.rss_mb,
    }, status


def close_run(result: dict[str, Any], daemon: Daemon, peer: MavlinkPeer, session: Any) -> None:
    """Close the session and the peer, stop the daemon; its log's failures and exit code into `result`."""
    if session is not None:
        session.close()
    peer.close()
    code = daemon.stop()
    result["log_failures"] = log_failures(daemon.log())
    result["log_failure_lines"] = failure_lines(daemon.log())
    result["stop_exit_code"] = code


def run_mavlink(inputs: int, seed: int, rate: float, baseline_s: float, tracker: str, fps: float, max_s: float,
                workdir: Path, progress: bool = True, signing: bool = False) -> dict[str, Any]:
    """The MAVLink fuzz against the daemon as a process; the figures as a dict (see the module docstring).
    signing: the daemon signs and refuses unsigned packets; the benchmark's autopilot and probes sign with its
    key, the fuzz does not (or with other keys)."""
    clip = write_clip(workdir / "clip")
    planned = list(mavlink_inputs(seed, inputs))  # made before the run: the sender only sends while it lasts
    mavlink_port, zenoh_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    key = bytes(random.Random(f"key{seed}").randrange(256) for _ in range(32)) if signing else None
    key_file = None
    if key is not None:
        key_file = workdir / "mavlink.key"
        key_file.write_text(key.hex())
    peer = MavlinkPeer(mavlink_port, key)
    daemon = Daemon(workdir, daemon_config(mavlink_port, zenoh_port,
                                           {"kind": "file", "path": str(clip), "loop": True, "realtime": True},
                                           tracker, fps, key_file))
    session = None
    result: dict[str, Any] = {"target": "mavlink", "seed": seed, "inputs_planned": inputs, "rate_per_s": rate,
                              "tracker": tracker, "source_fps": fps, "signing": signing, "commit": git_commit()}
    try:
        session = daemon_session(daemon, peer, zenoh_port)
        track = TrackCounter(session)
        if not wait_for(lambda: query_status(session, 1.0) is not None, 60.0):
            raise RuntimeError("the status query never answered")
        select_and_track(daemon, peer, track)
        daemon_port = peer.daemon_address[1] if peer.daemon_address else 0
        drops_before = udp_drops(daemon_port) or 0
        # the run without fuzz: same daemon, same clip, the same probes
        t0 = time.monotonic()
        base_probes = Probing(daemon, peer, session, t0).stop(after_s=baseline_s)
        t1 = time.monotonic()
        baseline = track.window(t0, t1)
        rss_before = rss_mb(daemon.proc.pid)
        # the fuzz
        probing = Probing(daemon, peer, session, t1)
        counts: dict[str, int] = {}
        sent_bytes = 0
        sent = 0
        for kind, data in paced(planned, rate, t1 + max_s, daemon):
            peer.send_raw(data)
            counts[kind] = counts.get(kind, 0) + 1
            sent += 1
            sent_bytes += len(data)
            if progress and sent % 10000 == 0:
                print(f"  {sent} inputs, {time.monotonic() - t1:.0f} s, rss {rss_mb(daemon.proc.pid)} MB",
                      flush=True)
        t2 = time.monotonic()
        probes = probing.stop()
        outcome, status = fuzz_outcome(daemon, peer, session, track, None, (baseline, base_probes),
                                       (track.window(t1, t2), probes), rss_before)
        drops = (udp_drops(daemon_port) or 0) - drops_before
        result.update({
            "inputs_sent": sent, "bytes_sent": sent_bytes, "by_kind": counts, "fuzz_s": round(t2 - t1, 1),
            "kernel_dropped": drops, **outcome,
            "daemon_counters": {k: v for k, v in (status or {}).get("counters", {}).items() if k.startswith("mavlink")},
            "signing_status": (status or {}).get("mavlink_signing"),
        })
        track.close()
    finally:
        close_run(result, daemon, peer, session)
    return result


def tcp_garbage(port: int, rng: random.Random, connections: int) -> dict[str, int]:
    """Open `connections` TCP connections to the daemon's Zenoh listen port, each sending 0..2000 random bytes
    (a Zenoh-looking length prefix half the time) before closing: the transport's own parsing of a stranger."""
    counts = {"sent": 0, "refused": 0}
    for _ in range(connections):
        data = bytes(rng.randint(0, 255) for _ in range(rng.randint(0, 2000)))
        if rng.random() < 0.5:
            data = struct.pack("<H", len(data)) + data  # Zenoh's TCP framing: a 16-bit length before each batch
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
                sock.sendall(data)
            counts["sent"] += 1
        except OSError:
            counts["refused"] += 1
    return counts


def run_zenoh(inputs: int, seed: int, rate: float, baseline_s: float, tracker: str, fps: float, max_s: float,
              workdir: Path, query_share: float = 0.25, progress: bool = True,
              exclude: tuple[str, ...] = (), garbage_connections: int = 0) -> dict[str, Any]:
    """The Zenoh fuzz: camera frames published by this benchmark at `fps` with fuzz payloads interleaved on the
    same key at `rate`, and random status queries (query_share of the inputs)."""
    from service.sources.zenoh_wire import encode_frame

    mavlink_port, zenoh_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    peer = MavlinkPeer(mavlink_port)
    daemon = Daemon(workdir, daemon_config(mavlink_port, zenoh_port, {"kind": "zenoh"}, tracker, fps))
    session = None
    camera_stop = threading.Event()
    result: dict[str, Any] = {"target": "zenoh", "seed": seed, "inputs_planned": inputs, "rate_per_s": rate,
                              "tracker": tracker, "source_fps": fps, "excluded": list(exclude), "commit": git_commit()}
    camera_ids = [0]
    try:
        session = daemon_session(daemon, peer, zenoh_port)
        track = TrackCounter(session)
        publisher = session.declare_publisher("fuzz/camera/frame")
        frames = [encode_frame(clip_frame(i), 0, 0.0) for i in range(CLIP_FRAMES)]
        lock = threading.Lock()

        def camera() -> None:
            """The camera: the clip at `fps`, frame ids from 0 (the fuzz's own valid frames use ids >= 2**40)."""
            next_at = time.monotonic()
            while not camera_stop.is_set():
                i = camera_ids[0]
                data = bytearray(frames[i % CLIP_FRAMES])
                struct.pack_into("<Qd", data, 16, i, time.time())
                with lock:
                    publisher.put(bytes(data))
                camera_ids[0] += 1
                next_at += 1.0 / fps
                camera_stop.wait(max(0.0, next_at - time.monotonic()))
        cam = threading.Thread(target=camera, daemon=True)
        cam.start()
        if not wait_for(lambda: (query_status(session, 1.0) or {}).get("source", {}).get("frames", 0) > 0, 60.0):
            raise RuntimeError(f"no frame reached the daemon; log:\n{daemon.log()[-3000:]}")
        select_and_track(daemon, peer, track)
        t0 = time.monotonic()
        base_probes = Probing(daemon, peer, session, t0).stop(after_s=baseline_s)
        t1 = time.monotonic()
        baseline = track.window(t0, t1, max_frame_id=2**40)
        rss_before = rss_mb(daemon.proc.pid)
        probing = Probing(daemon, peer, session, t1)
        rng = random.Random(seed)
        kinds, weights = zip(*((k, w) for k, w in ZENOH_FRAME_KINDS.items() if k not in exclude))
        counts: dict[str, int] = {}
        query_replies = 0
        query_errors = 0
        sent = 0
        for n in paced(range(inputs), rate, t1 + max_s, daemon):
            if rng.random() < query_share:
                key, params, payload, encoding = zenoh_query_input(rng, "fuzz")
                counts["query"] = counts.get("query", 0) + 1
                try:
                    selector = f"{key}?{params}" if params else key
                    for reply in session.get(selector, payload=payload, encoding=encoding, timeout=0.5):
                        query_replies += reply.ok is not None
                except Exception:  # noqa: BLE001 - a selector Zenoh itself refuses on this side
                    query_errors += 1
            else:
                kind = rng.choices(kinds, weights)[0]
                data = zenoh_frame_input(rng, kind, 2**40 + n)
                with lock:
                    publisher.put(data)
                counts[kind] = counts.get(kind, 0) + 1
            sent += 1
            if progress and sent % 2000 == 0:
                print(f"  {sent} inputs, {time.monotonic() - t1:.0f} s, rss {rss_mb(daemon.proc.pid)} MB", flush=True)
        garbage = tcp_garbage(zenoh_port, rng, garbage_connections) if daemon.alive() else {}
        t2 = time.monotonic()
        probes = probing.stop()
        outcome, status = fuzz_outcome(daemon, peer, session, track, 2**40, (baseline, base_probes),
                                       (track.window(t1, t2, max_frame_id=2**40), probes), rss_before)
        result.update({
            "inputs_sent": sent, "by_kind": counts, "fuzz_s": round(t2 - t1, 1),
            "query_replies": query_replies, "query_errors_local": query_errors, "tcp_garbage": garbage,
            "camera_frames_published": camera_ids[0], **outcome,
            "source": (status or {}).get("source"),
        })
        track.close()
    finally:
        camera_stop.set()
        close_run(result, daemon, peer, session)
    return result


# --- config.yaml mutations -----------------------------------------------------------------------------------
CONFIG_KINDS = {"wrong_type": 20, "out_of_range": 15, "unknown_key": 10, "delete_key": 8, "deep_nesting": 5,
                "huge_number": 10, "nan_string": 8, "yaml_special_float": 6, "empty_file": 2, "binary_file": 4,
                "truncated_text": 6, "random_text": 3, "recursive_anchor": 2, "non_mapping": 3, "several": 8}
ODD_VALUES: tuple[Any, ...] = (None, True, False, 0, -1, 1, 2**31, -2**31, 2**63, 10**30, 10**400, -(10**400), 1e308,
                               -1e308, 1e-308, 0.5, "", "x", "nan", "NaN", "inf", "-inf", "1e999", "0x10", "true",
                               "\u00e9\u4e2d", "a" * 10000, [], [1, 2], {}, {"a": 1}, [[[]]], {"x": {"y": {}}})


def leaf_paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (tuple of keys / indices) to a value in nested dicts and lists, containers included."""
    paths = [prefix] if prefix else []
    if isinstance(value, dict):
        for key, item in value.items():
            paths.extend(leaf_paths(item, prefix + (key,)))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            paths.extend(leaf_paths(item, prefix + (i,)))
    return paths


def get_path(doc: Any, path: tuple) -> Any:
    for part in path:
        doc = doc[part]
    return doc


def set_path(doc: Any, path: tuple, value: Any) -> None:
    get_path(doc, path[:-1])[path[-1]] = value


def nested(depth: int, kind: str) -> Any:
    value: Any = 1
    for _ in range(depth):
        value = [value] if kind == "list" else {"k": value}
    return value


def mutate_config(rng: random.Random, base: dict, kind: str) -> str | bytes:
    """One mutated config file (text, or bytes for a binary file) of the given kind (CONFIG_KINDS)."""
    doc = copy.deepcopy(base)
    paths = leaf_paths(doc)
    path = rng.choice(paths)
    current = get_path(doc, path)
    if kind == "wrong_type":
        set_path(doc, path, rng.choice(ODD_VALUES))
    elif kind == "out_of_range":
        if isinstance(current, bool) or not isinstance(current, (int, float)):
            numbers = [p for p in paths if isinstance(get_path(doc, p), (int, float))
                       and not isinstance(get_path(doc, p), bool)]
            path = rng.choice(numbers)
            current = get_path(doc, path)
        candidates = [-current, -1, 0, -1e-9, 256, 65536, 99999]
        try:
            candidates += [current * 1e6, current + 1e9]
        except OverflowError:  # an earlier mutation ("several") left a 400-digit number here
            pass
        set_path(doc, path, rng.choice(candidates))
    elif kind == "unknown_key":
        parents = [p for p in [()] + paths if isinstance(get_path(doc, p), dict)]
        parent = get_path(doc, rng.choice(parents))
        parent[rng.choice(("unknown", "kp ", "Kp", "max_rate_deg", "", "1", "\u00e9", "x" * 300))] = rng.choice(ODD_VALUES)
    elif kind == "delete_key":
        if len(path) >= 1:
            del get_path(doc, path[:-1])[path[-1]]
    elif kind == "deep_nesting":
        depth = rng.choice((50, 500, 5000))
        if rng.random() < 0.5:  # as YAML text (the parser's recursion), at a random key
            return yaml.safe_dump(doc).replace("tracker:", "tracker: " + "[" * depth + "]" * depth + "\nx_tracker:", 1) \
                if rng.random() < 0.3 else ("source: " + "[" * depth + "1" + "]" * depth + "\n")
        set_path(doc, path, nested(min(depth, 100), rng.choice(("list", "dict"))))  # the dumper recurses too
    elif kind == "huge_number":
        set_path(doc, path, rng.choice((10**400, -(10**400), 2**64, 10**19, 1e308, -1e308, 2**1000)))
    elif kind == "nan_string":
        set_path(doc, path, rng.choice(("nan", "NaN", ".nan", "inf", "-inf", ".inf", "1e999", "Infinity")))
    elif kind == "yaml_special_float":
        text = yaml.safe_dump(doc)
        lines = [i for i, line in enumerate(text.splitlines()) if re.search(r":\s+-?[0-9.]+$", line)]
        if lines:
            rows = text.splitlines()
            i = rng.choice(lines)
            rows[i] = re.sub(r":\s+-?[0-9.]+$", ": " + rng.choice((".nan", ".inf", "-.inf", ".NaN", "1e400")), rows[i])
            return "\n".join(rows) + "\n"
    elif kind == "empty_file":
        return rng.choice(("", "\n", "---\n", "# nothing\n", "~\n", "null\n"))
    elif kind == "binary_file":
        return rng.choice((bytes(rng.randint(0, 255) for _ in range(rng.randint(1, 2000))),
                           b"\xff\xfe" + yaml.safe_dump(doc).encode("utf-16-le"),
                           yaml.safe_dump(doc).encode() + b"\x00\xff\x80",
                           b"\x89PNG\r\n\x1a\n" + bytes(100)))
    elif kind == "truncated_text":
        text = yaml.safe_dump(doc)
        return text[:rng.randint(0, len(text) - 1)]
    elif kind == "random_text":
        return "".join(rng.choice("abc: -[]{},\n\t'\"&*!|>%@`#?0123456789.") for _ in range(rng.randint(1, 500)))
    elif kind == "recursive_anchor":
        return rng.choice(("tracker: &a {params: *a}\n", "tracker: {params: {redetect: &b {search: *b}}}\n",
                           "zenoh: {listen: &c [*c]}\n", "x: &d [*d]\n", "tracker: {params: &e {x: *e}}\n"))
    elif kind == "non_mapping":
        return rng.choice(("[1, 2, 3]\n", "42\n", "just a string\n", "- a\n- b\n", "!!binary aGVsbG8=\n",
                           "!!python/object:os.system {}\n", "? [a, b]\n: 1\n"))
    elif kind == "several":
        text: Any = doc
        for _ in range(rng.randint(2, 5)):
            sub = rng.choice(("wrong_type", "out_of_range", "unknown_key", "delete_key", "huge_number", "nan_string"))
            out = mutate_config(rng, text, sub)
            text = yaml.safe_load(out) if isinstance(out, str) else text
            if not isinstance(text, dict):
                return out
        return yaml.safe_dump(text)
    else:
        raise ValueError(f"unknown config mutation {kind!r}")
    return yaml.safe_dump(doc)


KEY_PATH = re.compile(r"^([A-Za-z_][\w ]*|\S*?)((?:\[\d+\])*(?:\.[^.:\[\s]+(?:\[\d+\])*)*): ")


def schema_paths() -> set[str]:
    """Every key path of the configuration schema (`gimbal.kp`, `zenoh.tls.certificate`, ...)."""
    import dataclasses

    from service.config import ServiceConfig

    out: set[str] = set()

    def walk(cls: type, prefix: str) -> None:
        for f in dataclasses.fields(cls):
            path = f"{prefix}.{f.name}" if prefix else f.name
            out.add(path)
            hint = cls.__annotations__.get(f.name)
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default  # type: ignore[misc]
            if dataclasses.is_dataclass(default):
                walk(type(default), path)
    walk(ServiceConfig, "")
    return out


def resolves(doc: Any, path: str) -> bool:
    """Whether a key path in the error messages' spelling (`a.b[2].c`) names an entry of a parsed document
    (keys may hold dots themselves: every way of reading the path is tried)."""
    if path == "":
        return True
    if isinstance(doc, list):
        index = re.match(r"\[(\d+)\]\.?", path)
        return bool(index) and int(index.group(1)) < len(doc) and resolves(doc[int(index.group(1))],
                                                                          path[index.end():])
    if not isinstance(doc, dict):
        return False
    for key, value in doc.items():
        name = str(key)
        rest = path[len(name):]
        if path.startswith(name) and (rest == "" or rest[0] in ".[") and resolves(value, rest.removeprefix(".")):
            return True
    return False


FILE_LEVEL = ("cannot read config file", "config file ", "config: must be a mapping")


def names_a_key(message: str, doc: Any, schema: set[str]) -> bool:
    """Whether a ConfigError message starts with a key path of the file or of the schema (`gimbal.kp: ...`,
    `zenoh.access.rules[0].messages: ...`), or is about the file as a whole."""
    if message.startswith(FILE_LEVEL):
        return True
    path = message.split(": ", 1)[0]
    if not path or len(path) > 400:
        return False
    quoted = re.fullmatch(r"(?:(.*)\.)?('.*'|\".*\")", path)  # an unknown key shown quoted: `gimbal.'kp '`
    if quoted and ": unknown key" in message:
        parent = quoted.group(1) or ""
        try:
            key = ast.literal_eval(quoted.group(2))
        except (ValueError, SyntaxError):
            return False
        node_ok = parent == "" or parent in schema or resolves(doc, parent)
        return node_ok and resolves(doc, f"{parent}.{key}" if parent else key)
    return path in schema or re.sub(r"\[\d+\]", "", path) in schema or resolves(doc, path)


def check_config_file(path: Path, schema: set[str]) -> tuple[str, str]:
    """Load one file as the daemon does: ("ok", ""), ("error", message naming a key), ("unnamed", message: an
    error that names no key) or ("crash", traceback)."""
    from service.config import ConfigError, load_config

    try:
        config = load_config(path)
        import jsar

        try:  # as Service() does at start: the tracker refuses bad parameters
            jsar.create(config.tracker.name, **config.tracker.params)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"tracker.params: {exc}") from exc
        return "ok", ""
    except ConfigError as exc:
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        except Exception:  # noqa: BLE001 - unreadable as YAML: only file-level messages can name it
            doc = None
        message = str(exc)
        return ("error" if names_a_key(message, doc, schema) else "unnamed"), message
    except BaseException:  # noqa: BLE001 - the fuzz's finding: a traceback instead of a ConfigError
        return "crash", traceback.format_exc(limit=6)


def safe_to_start(path: Path) -> bool:
    """Whether the daemon may be started on this file in a benchmark: it fails validation, or it loads with
    Zenoh on loopback only (no multicast scouting) and no RTP stream (nothing leaves the machine)."""
    from service.config import ConfigError, load_config
    from service.telemetry import endpoint_is_loopback

    try:
        config = load_config(path)
    except ConfigError:
        return True
    except Exception:  # noqa: BLE001 - a crash: the process run shows it too
        return True
    zenoh = config.zenoh
    return (not zenoh.multicast_scouting and not config.video.stream.enabled
            and all(endpoint_is_loopback(e) for e in (*zenoh.listen, *zenoh.connect)))


def run_config(inputs: int, seed: int, processes: int, max_s: float, workdir: Path) -> dict[str, Any]:
    """Mutate config.yaml `inputs` times, load each in process; start the daemon on `processes` of them."""
    base = yaml.safe_load((REPO / "config.yaml").read_text(encoding="utf-8"))
    base["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]  # not the default port
    rng = random.Random(seed)
    kinds, weights = zip(*CONFIG_KINDS.items())
    schema = schema_paths()
    outcomes: dict[str, int] = {}
    by_kind: dict[str, dict[str, int]] = {}
    failures: list[dict[str, str]] = []
    examples: dict[str, str] = {}
    start = time.monotonic()
    files: list[tuple[str, Path]] = []
    done = 0
    for n in range(inputs):
        if time.monotonic() - start > max_s:
            break
        kind = rng.choices(kinds, weights)[0]
        content = mutate_config(rng, base, kind)
        path = workdir / f"config_{n % 50}.yaml"
        path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
        outcome, message = check_config_file(path, schema)
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
        by_kind.setdefault(kind, {})[outcome] = by_kind.setdefault(kind, {}).get(outcome, 0) + 1
        examples.setdefault(f"{kind}:{outcome}", message[:200])
        if outcome in ("crash", "unnamed") and len(failures) < 20:
            failures.append({"kind": kind, "outcome": outcome, "message": message[-1500:],
                             "file_head": (content[:300] if isinstance(content, str) else repr(content[:120]))})
        if (processes and rng.random() < 4 * processes / max(inputs, 1) and len(files) < processes
                and safe_to_start(path)):
            keep = workdir / f"process_{len(files)}.yaml"
            keep.write_bytes(path.read_bytes())
            files.append((kind, keep))
        done += 1
    runs = [run_config_process(kind, path) for kind, path in files]
    return {"target": "config", "seed": seed, "inputs": done, "outcomes": outcomes, "by_kind": by_kind,
            "failures": failures, "examples": examples, "process_runs": runs,
            "process_failures": [r for r in runs if not r["ok"]], "seconds": round(time.monotonic() - start, 1),
            "commit": git_commit()}


def run_config_process(kind: str, path: Path, timeout_s: float = 60.0) -> dict[str, Any]:
    """`python -m service --config PATH` with the source and links made harmless (loopback, no Zenoh listen):
    exit 2 and `configuration error: KEY`, or a clean start (event=started) then SIGTERM and exit 0."""
    proc = subprocess.Popen([sys.executable, "-m", "service", "--config", str(path), "--mavlink",
                             f"udpout:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"], cwd=REPO,
                            env={**os.environ, **ONE_THREAD_ENV}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    lines: list[str] = []
    started = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "event=started" in line:
                started.set()
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and not started.is_set() and time.monotonic() < deadline:
        started.wait(0.2)
    if started.is_set():
        proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    reader.join(2.0)
    text = "".join(lines)
    error = re.search(r"configuration error: (.*)", text)
    ok = "Traceback" not in text and ((code == 2 and error is not None) or (started.is_set() and code == 0)
                                      or code == 1 and "event=startup_failed" in text)
    return {"kind": kind, "exit_code": code, "started": started.is_set(),
            "error": error.group(1)[:200] if error else None, "ok": ok,
            "tail": "" if ok else text[-1500:]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.fuzz", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("target", choices=("mavlink", "zenoh", "config"))
    parser.add_argument("--inputs", type=int, default=None, help="inputs to send (mavlink 100000, zenoh 20000, "
                        "config 5000)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rate", type=float, default=None, help="inputs per second (mavlink 2500, zenoh 400)")
    parser.add_argument("--baseline-s", type=float, default=15.0, help="the run without fuzz before it (s)")
    parser.add_argument("--tracker", default="jsar-re")
    parser.add_argument("--fps", type=float, default=20.0, help="the camera's frame rate")
    parser.add_argument("--max-s", type=float, default=600.0, help="bound on the fuzz's wall time (s)")
    parser.add_argument("--processes", type=int, default=12, help="config: daemon starts on mutated files")
    parser.add_argument("--signing", action="store_true", help="mavlink: the daemon signs and refuses unsigned "
                        "packets; the benchmark's autopilot and probes sign")
    parser.add_argument("--exclude", default="", help="zenoh: frame input kinds left out, comma-separated (e.g. "
                        "odd_size_frame: valid frames of other sizes, which stop or restart the track by design)")
    parser.add_argument("--tcp-garbage", type=int, default=0, help="zenoh: after the fuzz, this many TCP "
                        "connections to the daemon's Zenoh port sending random bytes")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="jsar-fuzz-") as tmp:
        workdir = Path(tmp)
        if args.target == "mavlink":
            result = run_mavlink(args.inputs or 100_000, args.seed, args.rate or 2500.0, args.baseline_s,
                                 args.tracker, args.fps, args.max_s, workdir, signing=args.signing)
        elif args.target == "zenoh":
            exclude = tuple(k for k in args.exclude.split(",") if k)
            unknown = [k for k in exclude if k not in ZENOH_FRAME_KINDS]
            if unknown:
                parser.error(f"--exclude: unknown kind {unknown[0]!r}; kinds: {', '.join(ZENOH_FRAME_KINDS)}")
            result = run_zenoh(args.inputs or 20_000, args.seed, args.rate or 400.0, args.baseline_s, args.tracker,
                               args.fps, args.max_s, workdir, exclude=exclude,
                               garbage_connections=args.tcp_garbage)
        else:
            result = run_config(args.inputs or 5000, args.seed, args.processes, args.max_s, workdir)
    result["command"] = "python -m bench.fuzz " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1, default=str))
    summary = {k: v for k, v in result.items() if k not in ("rss_samples", "examples", "by_kind", "failures")}
    summary["failures"] = [f"{f['kind']} {f['outcome']}: {f['message'].strip().splitlines()[-1][:160]}"
                           for f in result.get("failures", [])]
    print(json.dumps(summary, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
