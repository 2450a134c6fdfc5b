"""Autopilot fault (issue 42), with the daemon as a process on loopback: the autopilot goes silent (no
heartbeat) while the daemon tracks with gimbal rates and velocity guidance (GUIDED), then comes back.

"Survived": the daemon keeps running and tracking its camera; it reports the loss (status
`autopilot.state` heartbeat_lost, log event=autopilot_heartbeat_timeout and event=commands_held) within a
second of its heartbeat timeout (mavlink.heartbeat_timeout_s, 1 s here); no gimbal or guidance command
leaves it while the autopilot is silent; both resume by themselves when the heartbeat returns.
`run_silence` is shared with bench/faults.py, which runs the 10-s silence of the issue.
"""
from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

from tests.fault_rig import TARGET, FaultRig, Feeder, Publisher

GIMBAL, SETPOINT = "GIMBAL_MANAGER_SET_PITCHYAW", "SET_POSITION_TARGET_LOCAL_NED"
TIMEOUT_S = 1.0  # mavlink.heartbeat_timeout_s in the rig
ARDUCOPTER_GUIDED = 4


def run_silence(workdir: Path, silence_s: float) -> dict[str, Any]:
    """Track, silence the autopilot for silence_s, bring it back; the measured figures (s, counts).
    AssertionError naming what failed."""
    rig = FaultRig(workdir, "zenoh", {"guidance": {"mode": "velocity", "rate_hz": 10.0}},
                   autopilot_kwargs={"custom_mode": ARDUCOPTER_GUIDED}).start()
    camera = Publisher(rig)
    feeder = Feeder(camera).start()
    ap = rig.autopilot
    try:
        rig.meet_camera()
        rig.select(TARGET)
        assert ap.from_service.wait_for(lambda: len(rig.from_autopilot_view(GIMBAL)) >= 10
                                        and len(rig.from_autopilot_view(SETPOINT)) >= 3, 10.0), \
            f"no gimbal rates / setpoints before the fault; log:\n{rig.daemon.log_tail()}"
        silent_at = time.monotonic()
        ap.heartbeats_on = False  # the autopilot goes silent (its last heartbeat left <= 0.1 s ago)
        held_from = silent_at + TIMEOUT_S + 0.15  # the timeout, one frame and a packet in flight
        assert rig.wait_track(lambda s: time.monotonic() > held_from, 5.0) is not None
        status = rig.status()
        assert status["autopilot"]["state"] == "heartbeat_lost", status["autopilot"]
        reported = rig.log_lines(r"event=autopilot_heartbeat_timeout")
        assert reported and rig.log_lines(r"event=commands_held reason=autopilot_heartbeat_lost"), rig.daemon.log_tail()
        detect_lag_s = float(re.search(r"silent_s=([0-9.]+)", reported[-1]).group(1)) - TIMEOUT_S
        last_cmd = max(r.at for r in rig.from_autopilot_view(GIMBAL, silent_at - 1.0))
        # nothing at all while silent: wait out the silence on the event "a command arrived"
        end = silent_at + silence_s
        leaked = ap.from_service.wait_for(
            lambda: bool(rig.from_autopilot_view(GIMBAL, held_from) or rig.from_autopilot_view(SETPOINT, held_from)),
            max(0.0, end - time.monotonic()))
        assert not leaked, (f"commands sent while the autopilot was silent: "
                            f"{[r.msg for r in rig.from_autopilot_view(GIMBAL, held_from)][:3]} "
                            f"{[r.msg for r in rig.from_autopilot_view(SETPOINT, held_from)][:3]}")
        during = rig.status()
        assert during["track"]["state"] in ("tracking", "recovered", "lost"), "the track was dropped"
        assert during["counters"]["out_held"] > 0 and rig.daemon.alive()
        frames_during = during["counters"]["frames"] - status["counters"]["frames"]

        back_at = time.monotonic()
        ap.heartbeats_on = True
        assert ap.from_service.wait_for(lambda: bool(rig.from_autopilot_view(GIMBAL, back_at))
                                        and bool(rig.from_autopilot_view(SETPOINT, back_at)), 5.0), \
            f"commands did not resume; log:\n{rig.daemon.log_tail()}"
        gimbal_resume_s = rig.from_autopilot_view(GIMBAL, back_at)[0].at - back_at
        setpoint_resume_s = rig.from_autopilot_view(SETPOINT, back_at)[0].at - back_at
        assert rig.log_lines(r"event=commands_resumed") and rig.log_lines(r"event=autopilot_connected")
        after = rig.status()
        assert after["autopilot"]["state"] == "connected"
        return {"silence_s": silence_s, "detect_after_timeout_s": detect_lag_s,
                "last_command_after_silence_s": last_cmd - silent_at, "held": during["counters"]["out_held"],
                "frames_tracked_while_silent": frames_during, "gimbal_resume_s": gimbal_resume_s,
                "setpoint_resume_s": setpoint_resume_s}
    finally:
        feeder.close()
        code = rig.close()
        assert code == 0, rig.daemon.log_tail()


def test_autopilot_silent_then_back(tmp_path: Path) -> None:
    figures = run_silence(tmp_path, silence_s=3.0)
    print(f"\nautopilot silent {figures['silence_s']:.0f} s (heartbeat timeout {TIMEOUT_S:.0f} s): reported "
          f"{figures['detect_after_timeout_s']:.3f} s after the timeout (status, log); last command "
          f"{figures['last_command_after_silence_s']:.3f} s into the silence; {figures['held']} commands held, "
          f"{figures['frames_tracked_while_silent']} frames tracked meanwhile; back: gimbal rates after "
          f"{figures['gimbal_resume_s']:.3f} s, setpoints after {figures['setpoint_resume_s']:.3f} s")
    assert figures["detect_after_timeout_s"] < 1.0
    assert figures["last_command_after_silence_s"] < TIMEOUT_S + 0.15
    assert figures["frames_tracked_while_silent"] > 10
