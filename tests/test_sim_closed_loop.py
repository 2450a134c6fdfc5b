"""Closed loop with the real daemon: scene + mock autopilot (each flavour) + daemon subprocess over
loopback Zenoh (peer, multicast scouting off, explicit tcp/127.0.0.1) and UDP MAVLink, lockstep.

Timeline of one run (simulated seconds): selection at 0; the autopilot link drops at 3 for 5 s; (PX4)
the pilot re-engages OFFBOARD at 10; the car passes under a tree canopy at 16; the run ends at 24.
Each phase has its own test, so a failure names the phase.

Centring: the ground-truth centre of the car within |dx| <= 0.1 W and |dy| <= 0.1 H on >= 90 % of the
frames where >= 50 % of the car is visible, outside the link drop and the 4 s after it (the daemon
cannot command the gimbal while the link is down).

The ground: textured from real frames when JSAR_DATA_ROOT is set (CI always sets it; the thresholds were
set on it), else the procedural ground `make run` uses on a bare machine, with the same checks. Only the
replay of a real sequence needs the data (it skips without it).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import pytest

from sim.closed_loop import ClosedLoop, ClosedLoopConfig, RunResult
from gcs.cli import TrackingStatus
from sim.scene import SceneConfig
from sim.soak import SoakCriteria, analyse

pytestmark = pytest.mark.slow

DURATION_S = 24.0
DROP_START_S, DROP_S = 3.0, 5.0
DROP_END_S = DROP_START_S + DROP_S
RECENTRE_S = 4.0  # allowed to re-centre after the link is back
REENGAGE_S = 10.0  # px4: the pilot re-engages OFFBOARD after the link is back
OCCLUSION_S = 16.0  # the car passes under a canopy
OUT = Path(__file__).resolve().parent.parent / "out"  # git-ignored: annotated videos of the runs


@dataclass
class Scenario:
    """One closed-loop run and what the ground station saw."""

    flavour: str
    result: RunResult
    records_by_type: dict
    commands: list
    events: list
    statuses_while_tracking: list[TrackingStatus]
    stop_result: str
    status_after_stop: TrackingStatus | None
    timeout_s: float
    accel_m_s2: float  # the mock's braking (ArduCopter SITL's, 2.5 m/s/s)


def run_scenario(flavour: str, ground: str) -> Scenario:
    cfg = ClosedLoopConfig(flavour=flavour, duration_s=DURATION_S, guidance="velocity",
                           scene=SceneConfig(occlusion_times_s=(OCCLUSION_S,), texture=ground),
                           link_drops=((DROP_START_S, DROP_S),),
                           operator_modes=((REENGAGE_S, "OFFBOARD"),) if flavour == "px4" else (),
                           video_path=OUT / f"test_sim_closed_loop_{flavour}.avi")
    with ClosedLoop(cfg) as loop:
        result = loop.run()
        gcs = loop.gcs
        statuses = [s for s in gcs.statuses if s.status == 1]
        camera_id = gcs.cameras()[0].component_id
        stop = gcs.track_stop(camera_id).name
        # The stop takes effect with the next frame: keep the camera running until IDLE comes back.
        frame, _ = loop.render(DURATION_S)
        idle = None
        for _ in range(50):
            frame_id = loop.publish(frame)
            loop.camera.telemetry.wait_frame(frame_id, 2.0)
            idle = gcs.wait_status(lambda s: s.status == 0, 0.1)
            if idle is not None:
                break
        ap = loop.autopilot
        return Scenario(flavour, result, dict(ap.stats.received_by_type), ap.commands(), list(ap.model.events),
                        statuses, stop, idle, ap.model.config.setpoint_timeout_s,
                        ap.model.config.max_accel_m_s2)


def trace(result: RunResult) -> str:
    """Twice-a-second log of a run, for failure messages."""
    lines = []
    for r in result.records[::15]:
        cx, cy = r.truth.centre
        lines.append(f"t={r.time_s:5.1f} {r.state or '-':9s} visible={r.truth.visible_fraction:4.2f} "
                     f"dx={cx - result.width / 2:7.1f} dy={cy - result.height / 2:7.1f} {r.mode:8s} "
                     f"{'LINK DOWN ' if r.link_down else ''}v={r.vehicle_speed:4.1f} d={r.target_distance_m:5.1f}")
    return "\n".join(lines)


@pytest.fixture(scope="module")
def ground(request) -> str:
    """The scene's ground texture: "data" (real frames) when JSAR_DATA_ROOT is set, else "procedural"."""
    if os.environ.get("JSAR_DATA_ROOT"):
        request.getfixturevalue("data_root")  # skips, as before, when it does not name a directory
        return "data"
    return "procedural"


# The scenario tests share one worker: under xdist each worker would otherwise run both module-scoped scenarios.
ONE_WORKER = pytest.mark.xdist_group("closed-loop-scenarios")


@pytest.fixture(scope="module", params=["ardupilot", "px4"])
def scenario(request, ground) -> Scenario:
    return run_scenario(request.param, ground)


@ONE_WORKER
def test_daemon_survives_and_answers_every_frame(scenario):
    result = scenario.result
    assert result.daemon_alive, "daemon died"
    assert result.selection_result == "SUCCESS"
    answered = sum(r.state is not None for r in result.records)
    assert answered == len(result.records), f"{len(result.records) - answered} frames without telemetry"
    assert result.dropped_frames == 0  # lockstep: nothing to drop


@ONE_WORKER
def test_target_centred_on_90_percent_of_visible_frames(scenario):
    ratio = scenario.result.centring_ratio(exclude=((DROP_START_S, DROP_END_S + RECENTRE_S),))
    assert ratio >= 0.90, (f"{scenario.flavour}: car centred on only {ratio:.1%} of visible frames\n"
                           + trace(scenario.result))


@ONE_WORKER
def test_recovered_after_occlusion_and_recentred(scenario):
    records = scenario.result.records
    hidden = [r.time_s for r in records if abs(r.time_s - OCCLUSION_S) < 2.0 and not r.truth.visible]
    assert hidden, "the scenario must hide the car under the canopy"
    after = [r for r in records if r.time_s >= hidden[-1] + 3.0]
    assert len(after) > 60, "too few frames after the occlusion"
    visible = sum(r.truth.visible for r in after) / len(after)
    centred = sum(r.centred(scenario.result.width, scenario.result.height) for r in after) / len(after)
    tracking = sum(r.state in ("tracking", "recovered") for r in after) / len(after)
    assert visible == 1.0 and centred >= 0.9 and tracking >= 0.9, (
        f"after the occlusion: visible {visible:.0%}, centred {centred:.0%}, tracking {tracking:.0%}\n"
        + trace(scenario.result))


@ONE_WORKER
def test_link_drop_stops_guidance_within_firmware_timeout(scenario):
    records = scenario.result.records
    stop_by = DROP_START_S + scenario.timeout_s + 0.1
    # The setpoint times out (ArduPilot: stops, stays GUIDED; PX4: failsafe to Position mode, as PX4 SIH)...
    expected = "guided setpoint timeout" if scenario.flavour == "ardupilot" else "mode OFFBOARD -> POSCTL"
    event_times = [t for t, e in scenario.events if expected in e]
    assert event_times and DROP_START_S < event_times[0] <= stop_by, scenario.events
    # ... and the vehicle brakes at the firmware's deceleration (ArduCopter SITL: from 5 m/s in about 2 s)
    # until the link returns: speed within that braking envelope, and stopped once it has had the time.
    at_timeout = [r.vehicle_speed for r in records if r.time_s <= stop_by][-1]
    braking = [r for r in records if stop_by + 0.2 <= r.time_s < DROP_END_S]
    assert braking and all(r.vehicle_speed <= max(0.0, at_timeout - scenario.accel_m_s2 * (r.time_s - stop_by - 0.2))
                           + 0.05 for r in braking), [(round(r.time_s, 2), round(r.vehicle_speed, 2)) for r in braking]
    stopped_by = stop_by + 0.2 + at_timeout / scenario.accel_m_s2
    assert all(r.vehicle_speed < 0.05 for r in braking if r.time_s >= stopped_by)
    assert scenario.result.daemon_alive


@ONE_WORKER
def test_link_drop_resumes_cleanly(scenario):
    records = scenario.result.records
    setpoints_after = [c for c in scenario.commands if c.msg_type == "SET_POSITION_TARGET_LOCAL_NED"
                       and c.time_s >= DROP_END_S]
    gimbal_after = [c for c in scenario.commands if c.msg_type.startswith("GIMBAL_MANAGER_SET")
                    and c.time_s >= DROP_END_S and c.outcome.startswith("applied")]
    assert gimbal_after, "gimbal control did not resume after the link came back"
    window = [r for r in records if DROP_END_S + RECENTRE_S <= r.time_s < OCCLUSION_S - 2.0]
    assert window and all(r.truth.visible for r in window), "car lost from view after the link came back"
    centred = sum(r.centred(scenario.result.width, scenario.result.height) for r in window) / len(window)
    assert centred >= 0.9, f"car not re-centred within {RECENTRE_S} s of the link coming back\n" + trace(
        scenario.result)
    if scenario.flavour == "ardupilot":
        assert any(c.outcome == "applied" for c in setpoints_after), "velocity guidance did not resume in GUIDED"
    else:
        # PX4 stays in POSCTL until the pilot re-engages OFFBOARD, which PX4 allows only while setpoints
        # stream; the daemon must never switch modes itself.
        # Compared on the model's own clock: the switch is stamped with model.time_s, which accumulates
        # frame steps and so sits a rounding error away from REENGAGE_S.
        switches = [t for t, e in scenario.events if "POSCTL -> OFFBOARD (operator)" in e]
        assert switches, f"pilot could not re-engage OFFBOARD (no setpoint stream in POSCTL?): {scenario.events}"
        reengaged_s = switches[0]
        assert abs(reengaged_s - REENGAGE_S) < 0.1
        assert not [c for c in setpoints_after if c.outcome == "applied" and c.time_s < reengaged_s]
        assert any(c.outcome == "applied" for c in setpoints_after if c.time_s >= reengaged_s)


@ONE_WORKER
def test_vehicle_follows_with_bounded_distance(scenario):
    records = scenario.result.records
    resumed = DROP_END_S + 2.0 if scenario.flavour == "ardupilot" else REENGAGE_S + 1.0
    window = [r for r in records if resumed <= r.time_s < OCCLUSION_S - 1.0]
    first, last = window[0], window[-1]
    moved = math.hypot(last.vehicle_ne[0] - first.vehicle_ne[0], last.vehicle_ne[1] - first.vehicle_ne[1])
    car_moved = math.hypot(last.truth.target.north - first.truth.target.north,
                           last.truth.target.east - first.truth.target.east)
    assert moved > 0.7 * car_moved, f"vehicle moved {moved:.1f} m while the car moved {car_moved:.1f} m"
    assert last.target_distance_m < first.target_distance_m + 5.0, "vehicle falling behind"
    assert max(r.target_distance_m for r in records if r.time_s < OCCLUSION_S) < 80.0


@ONE_WORKER
def test_daemon_never_arms_or_changes_mode(scenario):
    sent = [c for c in scenario.commands if c.msg_type in ("COMMAND_LONG", "COMMAND_INT")
            and c.fields.get("command") in (176, 400)]
    assert not sent and "SET_MODE" not in scenario.records_by_type


@ONE_WORKER
def test_mavsdk_ground_station_selects_gets_status_and_stops(scenario):
    assert scenario.result.selection_result == "SUCCESS"
    assert len(scenario.statuses_while_tracking) >= 10
    last = scenario.statuses_while_tracking[-1]
    assert all(0.0 <= v <= 1.0 for v in last.rectangle) and last.rectangle[0] < last.rectangle[2]
    assert scenario.stop_result == "SUCCESS"
    assert scenario.status_after_stop is not None and scenario.status_after_stop.status_name == "IDLE"


def test_soak_flat_memory_and_latency(ground):
    """A bounded soak (62 s simulated, lockstep): RSS not sloping after warm-up (a one-off step, e.g.
    the first large re-detection, is not a leak), per-frame CPU (hence latency) not growing, the car in
    view; all judged so that another process on the machine does not decide (see sim.soak). 62 s: the
    bridge at 32 s (the car comes out turned) and the canopy at 57 s (a coasting track next to the car must
    not end the loss on the canopy). The one-hour soak: `python -m sim.soak --minutes 60`."""
    duration = 62.0
    cfg = ClosedLoopConfig(duration_s=duration, guidance="velocity", rss_every_s=1.0,
                           scene=SceneConfig(texture=ground))
    with ClosedLoop(cfg) as loop:
        result = loop.run()
    report = analyse(result, duration, cfg.fps)
    problems = report.failures(SoakCriteria())
    assert not problems, f"{problems}; {report.describe()}; rss {result.rss_kib}; cpu {result.cpu_s}"
    # After the canopy the box is on the car again (in-view alone would not tell yet: a track left on the
    # canopy takes a few seconds to lose the car from the image).
    last_second = [r for r in result.records if r.time_s >= duration - 1.0 and r.box is not None and r.truth.visible]
    assert last_second, "the car must be visible in the last second"
    # in the car's sides, not the box's: a box that has flattened on the car (seen: 47x13 px on a 58x55 px car,
    # its centre 15 px from the car's) is on it, though half its own side off
    misses = [math.dist(r.truth.centre, (r.box[0] + r.box[2] / 2, r.box[1] + r.box[3] / 2))
              / math.sqrt(r.truth.box[2] * r.truth.box[3]) for r in last_second]
    assert sorted(misses)[len(misses) // 2] < 0.5, f"box off the car by {sorted(misses)[len(misses) // 2]:.2f} car sides\n" + trace(result)


def test_soak_memory_criterion_catches_an_injected_per_frame_leak():
    """The same criterion on the daemon with 16 KiB leaked per frame (tests.leaky_service, about 1690 MiB/h
    at 30 fps): it fails. The RSS shows only part of a leak at first (seen: 331 MiB/h of 844 injected),
    as malloc hands out freed heap that is still resident before touching new pages; and with no
    occlusion in this scene, as a re-detection leaves up to ~24 MiB of such heap (see sim.soak)."""
    from tests.leaky_service import LEAK_BYTES_PER_FRAME
    duration = 20.0
    cfg = ClosedLoopConfig(duration_s=duration, guidance="velocity", rss_every_s=1.0,
                           scene=SceneConfig(occlusion_times_s=(), occlusion_period_s=0.0),
                           daemon_module="tests.leaky_service")
    with ClosedLoop(cfg) as loop:
        result = loop.run()
    report = analyse(result, duration, cfg.fps)
    problems = report.failures(SoakCriteria())
    leak_mib_h = LEAK_BYTES_PER_FRAME * cfg.fps * 3600.0 / 2 ** 20
    assert any("RSS keeps growing" in p for p in problems), f"{problems}; {report.describe()}"
    assert report.rss.slope_mib_h <= 1.3 * leak_mib_h, report.describe()  # no more than was leaked


def test_lockstep_run_is_reproducible():
    """The same lockstep scenario twice (PX4: gimbal claim, then 282 rates; velocity guidance): every
    frame's state, box, car position in the image and vehicle position, and every control message the
    daemon sent, are identical. `python -m sim.repro` runs longer scenarios (link drop, occlusion)."""
    from sim.repro import first_difference, run_once
    cfg = ClosedLoopConfig(flavour="px4", duration_s=4.0, guidance="velocity")
    first, second = run_once(cfg), run_once(cfg)
    assert first.gimbal_command_timeouts == 0 and second.gimbal_command_timeouts == 0
    # the daemon's no-frames hold runs on its wall clock: a sim slower than that gap (a machine overloaded)
    # would make the runs part for that reason, said here rather than as a difference of boxes
    assert (first.frame_gap_holds, second.frame_gap_holds) == (0, 0)
    assert len(first.frames) == 120 and first.commands
    difference = first_difference(first, second)
    assert difference is None, difference


def test_the_demo_replays_a_real_sequence_through_the_closed_loop(data_root, tmp_path, monkeypatch, capsys):
    """`python -m sim.demo --replay OTB_Crossing --pace lockstep --duration 2`: the first ground-truth box is
    selected through the ground station, every frame is answered, the box stays on the ground truth."""
    import argparse

    from sim import demo
    from tests.helpers import real_sequence

    real_sequence(data_root, "OTB_Crossing")  # skip when the sequence is not there
    monkeypatch.setattr(demo, "OUT_DIR", tmp_path / "out")
    args = argparse.Namespace(replay=str(data_root / "OTB_Crossing"), flavour="ardupilot", duration=2.0,
                              pace="lockstep", guidance="off", tracker=None, loop=False, no_web=True, web_port=8080)
    assert demo.run_replay(args) == 0
    lines = [line.strip() for line in capsys.readouterr().out.splitlines()]

    def value(key: str) -> str:
        return next(line[len(key):].split()[0] for line in lines if line.startswith(key + " "))

    assert value("track_rectangle") == "SUCCESS"
    assert value("frames_sent") == value("frames_processed") == "60"  # 2 s at 30 fps after the init frame
    assert value("lost") == "0" and value("dropped_frames") == "0"
    assert float(value("centre_error_px_median")) < 5.0
    assert (tmp_path / "out" / "demo_replay_OTB_Crossing.avi").stat().st_size > 0
