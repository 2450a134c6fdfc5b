"""Fuzzing the daemon's MAVLink port (issue 42): the short bounded version of `python -m bench.fuzz mavlink`
(the daemon as a process, seeded inputs of every kind), the completeness of the fuzzer's command list, and the
defects the fuzz found as regression tests (a UDP datagram ending inside a packet swallowed the next command;
pymavlink's per-name message history grew without bound)."""
from __future__ import annotations

import os
import random
import socket
import time
import tracemalloc
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import pytest  # noqa: E402
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from pymavlink.dialects.v20 import all as dialect  # noqa: E402

from bench.fuzz import (GCS, HANDLED_COMMANDS, MAVLINK_KINDS, encode, mavlink_input, mavlink_inputs,  # noqa: E402
                        random_command, random_message, run_mavlink)
from service.config import MavlinkConfig  # noqa: E402
from service.mavlink.commands import decide  # noqa: E402
from service.mavlink.link import MavlinkLink  # noqa: E402
from sim.ports import free_udp_port  # noqa: E402


def test_the_fuzzer_sends_every_command_the_camera_decides_on() -> None:
    """Every command id but HANDLED_COMMANDS is refused as unsupported by commands.decide: the fuzzer's list is
    the camera's whole command surface."""
    params = (0.5, 0.5, 0.1, 0.6, 0.0, 0.0, 0.0)
    decided = {command for command in range(65536)
               if "is not supported by this camera" not in decide(command, params, 100).reason}
    assert decided == set(HANDLED_COMMANDS)


def test_the_inputs_are_reproducible_and_cover_every_kind() -> None:
    first = list(mavlink_inputs(5, 3000))
    assert first == list(mavlink_inputs(5, 3000))
    assert first != list(mavlink_inputs(6, 3000))
    assert {kind for kind, _ in first} == set(MAVLINK_KINDS)
    framings = {data[0] for kind, data in first if kind in ("handled_v2", "handled_v1")}
    assert framings == {0xFD, 0xFE}  # MAVLink 2 and MAVLink 1
    signed = [data for kind, data in first if kind.startswith("signed")]
    assert signed and all(data[0] == 0xFD and data[2] & 0x01 for data in signed)


@pytest.fixture
def link_and_sender():
    """A MavlinkLink listening on a loopback UDP port (udpin), and a socket that sends to it."""
    port = free_udp_port()
    link = MavlinkLink(MavlinkConfig(url=f"udpin:127.0.0.1:{port}"), source_system=1)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield link, lambda data: sender.sendto(data, ("127.0.0.1", port))
    sender.close()
    link.close()


def command(seq: int = 0) -> bytes:
    mav = dialect.MAVLink(None, srcSystem=GCS[0], srcComponent=GCS[1])
    mav.seq = seq
    return bytes(mav.command_long_encode(1, 100, dialect.MAV_CMD_REQUEST_MESSAGE, 0, 275, 0, 0, 0, 0, 0, 0).pack(mav))


def received(link: MavlinkLink, timeout_s: float = 2.0) -> list[object]:
    """Every message the link returns until it has been quiet for 0.3 s (or timeout_s)."""
    out: list[object] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = link.recv(timeout_s=0.3)
        if msg is None:
            break
        out.append(msg)
    return out


def drain(link: MavlinkLink, count: int) -> int:
    """Read up to `count` messages, stopping early when none comes within 0.5 s; how many came."""
    for got in range(count):
        if link.recv(timeout_s=0.5) is None:
            return got
    return count


def test_a_datagram_ending_inside_a_packet_does_not_swallow_the_next_command(link_and_sender) -> None:
    """Regression (bench.fuzz: the first command after the fuzz went unanswered): a truncated packet, or one
    whose length byte says more than it holds, is dropped at the end of its datagram; the command in the next
    datagram arrives."""
    link, send = link_and_sender
    valid = command()
    wrong_length = bytearray(command(1))
    wrong_length[1] = 250
    for junk in (valid[:7], valid[:-3], bytes(wrong_length)):
        bad_before = link.bad_packets
        send(junk)
        send(command(2))
        messages = received(link)
        assert [m.get_type() for m in messages] == ["COMMAND_LONG"], (junk, messages)
        assert messages[0].param1 == 275
        assert link.bad_packets == bad_before + 1  # the unfinished packet is counted


def test_several_packets_in_one_datagram_all_arrive(link_and_sender) -> None:
    link, send = link_and_sender
    send(command(0) + command(1) + command(2))
    assert [m.get_seq() for m in received(link)] == [0, 1, 2]


def test_made_up_names_do_not_grow_the_links_memory(link_and_sender) -> None:
    """Regression (bench.fuzz named_message): pymavlink kept every PARAM_VALUE / NAMED_VALUE_* / DEBUG_VECT by
    its name, about 1 kB per packet without bound. 4000 such packets from the fuzzer now keep < 0.5 MB."""
    link, send = link_and_sender
    rng = random.Random(4)
    packets = [mavlink_input(rng, "named_message") for _ in range(4000)]
    for packet in packets[:200]:  # warm-up: the first of each type, caches
        send(packet)
    drain(link, 200)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    got = 0
    for start in range(200, len(packets), 50):
        for packet in packets[start:start + 50]:
            send(packet)
        got += drain(link, 50)
    grown = sum(stat.size_diff for stat in tracemalloc.take_snapshot().compare_to(before, "filename"))
    tracemalloc.stop()
    assert got > 3000  # the packets were parsed (a few share a datagram's fate on a busy machine)
    assert grown < 512 * 1024, f"{grown / 1e6:.1f} MB kept"


_CAMERA: list = []


def camera_component() -> object:
    """One CameraComponent (not started) on a real link to a loopback port, with a frame source that has frames:
    the receive thread's handler is called directly with parsed messages."""
    if not _CAMERA:
        from service.config import config_from_mapping
        from service.mavlink.camera import CameraComponent
        from service.sources.base import LatestSlot

        config = config_from_mapping({"tracker": {"name": "csrt", "range_size_band": 0},
                                      "mavlink": {"url": f"udpout:127.0.0.1:{free_udp_port()}", "system_id": 1}})
        link = MavlinkLink(config.mavlink, 1)
        _CAMERA.append(CameraComponent(config, link, LatestSlot(), frame_size=lambda: (320, 240),
                                       source_ok=lambda: True, source_reason=lambda: "", source_state=lambda: "ok"))
    return _CAMERA[0]


@settings(max_examples=400, deadline=None, derandomize=True)
@given(name=st.sampled_from(["COMMAND_LONG", "COMMAND_INT", "HEARTBEAT", "GLOBAL_POSITION_INT", "ATTITUDE",
                             "GIMBAL_DEVICE_ATTITUDE_STATUS", "GIMBAL_MANAGER_STATUS", "PARAM_VALUE",
                             "NAMED_VALUE_FLOAT", "STATUSTEXT", "COMMAND_ACK"]),
       seed=st.integers(0, 2**32), as_autopilot=st.booleans())
def test_handled_messages_with_random_fields_raise_nothing_in_the_camera(name: str, seed: int,
                                                                        as_autopilot: bool) -> None:
    """Hypothesis (derandomized): the handled messages with random fields (NaN, infinities, extremes), from the
    autopilot's system or another, through the camera's handler (commands, the autopilot view) and the status
    messages it then sends: no exception (the receive thread would log message_handling_failed)."""
    from service.domain import TrackSnapshot

    camera = camera_component()
    rng = random.Random(seed)
    msg = random_command(rng, name) if name in ("COMMAND_LONG", "COMMAND_INT") and rng.random() < 0.7 else \
        random_message(rng, name)
    parser = dialect.MAVLink(None)
    parsed = parser.parse_buffer(encode(rng, msg, source=(1, 1) if as_autopilot else None))
    assert parsed and parsed[0].get_type() == name
    camera._handle(parsed[0], 1)
    camera.publish(TrackSnapshot())
    camera._send_image_status()
    camera._send_geo_status()


def test_the_daemon_survives_a_short_mavlink_fuzz(tmp_path: Path) -> None:
    """5,000 inputs of every kind at 2,500 a second into the daemon's port (a process, csrt tracking a clip at
    20 fps): it keeps running, answers every selection probe and status query during the fuzz and a command
    right after it at the first attempt, logs no failure, keeps its frame rate and its memory."""
    result = run_mavlink(inputs=5000, seed=2, rate=2500.0, baseline_s=4.0, tracker="csrt", fps=20.0, max_s=20.0,
                         workdir=tmp_path, progress=False)
    assert result["inputs_sent"] == 5000 and result["kernel_dropped"] == 0, result
    assert result["crashes"] == 0 and result["hangs"] == 0 and result["stop_exit_code"] == 0, result
    assert result["log_failures"] == {}, result["log_failure_lines"]
    during = result["during"]
    assert during["selection_probes_answered"] == during["selection_probes"] > 0, during
    assert during["status_answered"] == during["status_queries"] > 0, during
    assert result["command_after_fuzz"]["attempt"] == 1, result["command_after_fuzz"]
    assert result["reselected_after_fuzz"], result
    # a paced 20 fps camera, the same daemon just before: tolerant of a machine other work keeps busy
    assert result["baseline"]["frames"] > 0 and result["frame_rate_ratio"] >= 0.6, result
    assert result["memory"]["rss_growth_mb"] < 15, result["memory"]
    assert result["daemon_counters"]["mavlink_bad_packets"] > 1000  # the malformed inputs reached the parser


def test_a_non_finite_attitude_or_an_impossible_position_keeps_the_last_good_pose() -> None:
    """Regression (bench.fuzz mavlink, 100,000 inputs: 10 event=step_failed, each stopping the track): ATTITUDE
    with NaN / infinite angles and GLOBAL_POSITION_INT off the globe from the autopilot's system reached the
    loop's geometry (math domain error, non-finite sightings). They are ignored; finite ones still update."""
    from service.mavlink.autopilot import AutopilotView, observe

    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = dialect.MAVLink(None)

    def heard(msg: object) -> object:
        return parser.parse_buffer(msg.pack(mav))[0]
    view = AutopilotView(system_id=1, attitude=(0.1, -0.2, 0.3), position=(47.0, 8.0, 500.0, 30.0))
    for roll, pitch, yaw in ((float("nan"), 0, 0), (0, float("inf"), 0), (0, 0, -float("inf"))):
        assert observe(view, heard(dialect.MAVLink_attitude_message(0, roll, pitch, yaw, 0, 0, 0)), 1.0, 1) == view
    for lat, lon in ((2**31 - 1, 0), (0, 1_800_000_001), (-900_000_001, 0)):
        assert observe(view, heard(dialect.MAVLink_global_position_int_message(0, lat, lon, 0, 0, 0, 0, 0, 0)),
                       1.0, 1) == view
    moved = observe(view, heard(dialect.MAVLink_attitude_message(0, 0.0, 0.5, 3.0, 0, 0, 0)), 1.0, 1)
    assert moved.attitude == pytest.approx((0.0, 0.5, 3.0))
    placed = observe(view, heard(dialect.MAVLink_global_position_int_message(0, -899_999_999, 1_799_999_999, 0, 0,
                                                                               0, 0, 0, 0)), 1.0, 1)
    assert placed.position[:2] == pytest.approx((-89.9999999, 179.9999999))


def test_a_ground_estimate_past_the_horizon_or_the_pole_is_none_and_geo_status_encodes() -> None:
    """Regression (bench.fuzz mavlink: event=message_handling_failed, struct.error 'i' format): a grazing ray from
    a made-up height (GLOBAL_POSITION_INT relative_alt up to 2,147 km) put the ground target thousands of km
    away, past the pole, and CAMERA_TRACKING_GEO_STATUS could not encode its latitude. Beyond the horizon there
    is no estimate; a valid one still encodes, its longitude wrapped."""
    import numpy as np

    from service.control.geo import VehiclePose, locate_on_ground
    from service.mavlink import messages

    grazing = np.array([1.0, 0.0, 2e-6])
    high = VehiclePose(89.9, 179.99, 2_000_000.0, 1_900_000.0, 0.0, 0.0, 0.0)
    assert locate_on_ground(high, grazing) is None
    assert locate_on_ground(VehiclePose(47.0, 8.0, 600.0, 100.0, 0.0, 0.0, 0.0), grazing) is None  # past 35.7 km
    east = np.array([0.0, 0.8, 0.6])
    target = locate_on_ground(VehiclePose(10.0, 179.9999, 600.0, 100.0, 0.0, 0.0, 0.0), east)
    assert target is not None and -180.0 <= target.lon_deg < -179.99 and target.ground_range_m == pytest.approx(133.3, abs=0.1)
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=100)
    packet = messages.tracking_geo_status(mav, 2, target, 600.0).pack(mav)
    decoded = dialect.MAVLink(None).parse_buffer(packet)[0]
    assert decoded.lon == round(target.lon_deg * 1e7)
