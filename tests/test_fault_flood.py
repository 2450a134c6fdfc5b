"""Command flood (issue 42), with the daemon as a process on loopback: a ground station sends COMMAND_LONG
to the camera at 1,000 a second while it tracks a camera (10 fps here, 30 in bench/faults.py). The tracking frame rate holds (the
frames the daemon processed per second, against the mean of the same windows just before and after
the flood, as a ratio), and every command is answered: accepted, or refused with its result code (the reason in the
log, the status's `mavlink_refusals` and, for the operator's commands, STATUSTEXT). ACKs are counted
per command. `run_flood` is shared with bench/faults.py, which floods for the issue's 10 s.
"""
from __future__ import annotations

import collections
import math
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402

from tests.fault_rig import CAMERA, TARGET, FaultRig, Feeder, Publisher  # noqa: E402

NAN = float("nan")
# (command, params, expected MAV_RESULT): a ground station polling and mistyping, not selecting (a flood of
# valid selections would restart the track on every frame by design)
FLOOD_COMMANDS: list[tuple[int, list[float], int]] = [
    (512, [259, 0, 0, 0, 0, 0, 0], 0),  # REQUEST_MESSAGE(CAMERA_INFORMATION): ACCEPTED, sent again
    (511, [275, 50_000, 0, 0, 0, 0, 0], 0),  # SET_MESSAGE_INTERVAL(275, 20 Hz, as the rig has it): ACCEPTED
    (512, [33, 0, 0, 0, 0, 0, 0], 3),  # REQUEST_MESSAGE(GLOBAL_POSITION_INT): UNSUPPORTED (not a camera's)
    (31_000, [0, 0, 0, 0, 0, 0, 0], 3),  # an unknown command: UNSUPPORTED
    (2005, [0.6, 0.6, 0.4, 0.4, 0, 0, 0], 2),  # TRACK_RECTANGLE inverted: DENIED (+ STATUSTEXT)
    (2004, [NAN, 0.5, 0.1, 0, 0, 0, 0], 2),  # TRACK_POINT x NaN: DENIED (+ STATUSTEXT)
    (2010, [7, 0, 0, 0, 0, 0, 0], 2),  # STOP_TRACKING for camera 7: DENIED (not this camera; the track goes on)
]


class Flooder:
    """A ground station (255/191) that sends COMMAND_LONG at a fixed rate and counts the ACKs by
    (command, result) without storing messages (its receive thread must keep up with the answers)."""

    def __init__(self, gcs_port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=255, source_component=191)
        self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)  # the answers come in bursts too
        self.acks: collections.Counter[tuple[int, int]] = collections.Counter()
        self.sent: collections.Counter[int] = collections.Counter()
        self.cond = threading.Condition()
        self._stop = threading.Event()
        self._receiver = threading.Thread(target=self._receive, name="flood-rx", daemon=True)
        self._receiver.start()
        self.conn.mav.send(self.conn.mav.heartbeat_encode(6, 8, 0, 0, 4))  # the autopilot peer learns our address

    def _receive(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
            if msg is not None and msg.get_srcComponent() == CAMERA[1]:
                with self.cond:
                    self.acks[(msg.command, msg.result)] += 1
                    self.cond.notify_all()

    def flood(self, rate_hz: float, seconds: float) -> float:
        """Send rate_hz commands a second for `seconds` (in ticks of 10 ms), cycling FLOOD_COMMANDS;
        returns the seconds it took (the pacing is the sender's own clock)."""
        tick_s, began = 0.01, time.monotonic()
        total = int(round(rate_hz * seconds))
        per_tick = max(1, int(round(rate_hz * tick_s)))
        done = 0
        for tick in range(math.ceil(total / per_tick)):
            self._stop.wait(max(0.0, began + tick * tick_s - time.monotonic()))  # pacing, not synchronisation
            for _ in range(min(per_tick, total - done)):
                command, params, _ = FLOOD_COMMANDS[done % len(FLOOD_COMMANDS)]
                self.conn.mav.send(self.conn.mav.command_long_encode(*CAMERA, command, 0, *params))
                self.sent[command] += 1
                done += 1
        return time.monotonic() - began

    def answered(self) -> int:
        with self.cond:
            return sum(self.acks.values())

    def wait_answered(self, count: int, timeout_s: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: sum(self.acks.values()) >= count, timeout=timeout_s)

    def close(self) -> None:
        self._stop.set()
        self._receiver.join(1.0)
        self.conn.close()


def frames_per_second(rig: FaultRig, seconds: float, during: threading.Event | None = None) -> tuple[float, float]:
    """The daemon's processed frames per second (its status counter) and CPU share over `seconds`."""
    first, t0, cpu0 = rig.status()["counters"]["frames"], time.monotonic(), rig.daemon.cpu_s()
    (during or threading.Event()).wait(seconds)  # the measuring window (a duration, not a synchronisation)
    last, t1, cpu1 = rig.status()["counters"]["frames"], time.monotonic(), rig.daemon.cpu_s()
    return (last - first) / (t1 - t0), (cpu1 - cpu0) / (t1 - t0)


def run_flood(workdir: Path, rate_hz: float, seconds: float, camera_fps: float = 30.0) -> dict[str, Any]:
    """Track a `camera_fps` camera; its frame rate for `seconds` without the flood, while flooding, and without
    again (the baseline is the mean of the two windows around the flood); the figures."""
    rig = FaultRig(workdir, "zenoh").start()
    camera = Publisher(rig, fps=camera_fps)
    feeder = Feeder(camera).start()
    flooder: Flooder | None = None
    try:
        rig.meet_camera()
        rig.select(TARGET)
        rig.gcs.close()  # from here the flooder is the only ground station (its own receive thread keeps up)
        rig.gcs = flooder = Flooder(rig.autopilot.links["gcs"].sock.getsockname()[1])  # type: ignore[assignment]
        baseline_fps, baseline_cpu = frames_per_second(rig, seconds)
        refusals_before = {(r["command"], r["result"]): r["count"] for r in rig.status()["mavlink_refusals"]}
        result: dict[str, float] = {}
        sender = threading.Thread(target=lambda: result.update(took_s=flooder.flood(rate_hz, seconds)), daemon=True)
        sender.start()
        flood_fps, flood_cpu = frames_per_second(rig, seconds)
        sender.join(seconds + 30.0)
        # the same window once more after the flood: the machine's other load drifts, the mean of the two is fairer
        after_fps, after_cpu = frames_per_second(rig, seconds)
        baseline_fps, baseline_cpu = (baseline_fps + after_fps) / 2, (baseline_cpu + after_cpu) / 2
        sent = sum(flooder.sent.values())
        all_answered = flooder.wait_answered(sent, 10.0)
        status = rig.status()
        assert rig.daemon.alive()
        assert status["track"]["state"] in ("tracking", "recovered"), status["track"]
        by_result = collections.Counter()
        for (command, code), count in flooder.acks.items():
            by_result[code] += count
        wrong = {key: count for key, count in flooder.acks.items()
                 if key not in {(c, r) for c, _, r in FLOOD_COMMANDS}}
        refusals = {(r["command"], r["result"]): (r["count"] - refusals_before.get((r["command"], r["result"]), 0),
                                                  r["reason"]) for r in status["mavlink_refusals"]}
        return {"rate_hz": rate_hz, "seconds": seconds, "sent": sent, "send_s": result.get("took_s", math.nan),
                "answered": flooder.answered(), "all_answered": all_answered, "wrong_results": wrong,
                "by_result": dict(by_result), "acks": dict(flooder.acks), "sent_by_command": dict(flooder.sent),
                "baseline_fps": baseline_fps, "flood_fps": flood_fps, "ratio": flood_fps / baseline_fps,
                "baseline_cpu": baseline_cpu, "flood_cpu": flood_cpu, "refusals": refusals,
                "dropped_frames": status["counters"]["dropped_frames"]}
    finally:
        feeder.close()
        code = rig.close()
        assert code == 0, rig.daemon.log_tail()


def summary(figures: dict[str, Any]) -> str:
    names = {0: "ACCEPTED", 2: "DENIED", 3: "UNSUPPORTED", 1: "TEMPORARILY_REJECTED", 4: "FAILED"}
    results = ", ".join(f"{names.get(k, k)} {v}" for k, v in sorted(figures["by_result"].items()))
    return (f"flood {figures['rate_hz']:.0f}/s for {figures['seconds']:.0f} s: {figures['sent']} sent in "
            f"{figures['send_s']:.2f} s, {figures['answered']} answered ({results}); frame rate "
            f"{figures['flood_fps']:.1f} fps against {figures['baseline_fps']:.1f} without (ratio "
            f"{figures['ratio']:.2f}); daemon CPU {figures['flood_cpu']:.2f} against {figures['baseline_cpu']:.2f} cores")


def test_a_command_flood_is_answered_and_the_frame_rate_holds(tmp_path: Path) -> None:
    # A 10-fps camera: within what the daemon tracks with the other core busy (about 17 fps on one quiet core,
    # 9-12 beside another test), so the ratio says whether the flood costs frames, not how busy the machine is.
    # bench/faults.py floods a 30-fps camera, where the daemon is CPU-bound.
    figures = run_flood(tmp_path, rate_hz=1000.0, seconds=2.0, camera_fps=10.0)
    print("\n" + summary(figures))
    assert figures["sent"] == 2000
    assert figures["all_answered"] and figures["answered"] == figures["sent"], figures["acks"]
    assert not figures["wrong_results"], figures["wrong_results"]
    # each kind answered as often as it was sent, with its result
    for command, count in figures["sent_by_command"].items():
        assert sum(n for (c, _), n in figures["acks"].items() if c == command) == count, (command, figures["acks"])
    # every refusal kind carries its reason in the status
    for (command, result), (count, reason) in figures["refusals"].items():
        assert reason, (command, result)
    # 0.7: two adjacent 2-s windows on a shared 2-core machine differ by up to ~20 % without any flood
    assert figures["ratio"] > 0.7, f"frame rate fell to {figures['ratio']:.2f} of its value without the flood"
