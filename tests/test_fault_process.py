"""Process fault (issue 42) without systemd: the daemon SIGKILLed while it tracks, then started again in the
same runtime directory, as systemd's Restart=on-failure does with RuntimeDirectoryPreserve=restart
(`$RUNTIME_DIRECTORY`; the real restart under systemd: tests/test_deploy_systemd.py, `make check-systemd`).

It comes back idle and says so: the log's event=restarted_after_unclean_exit naming the killed pid, the
status's run.previous_exit "unclean", 275 IDLE; it zeroes the gimbal rates once (ArduPilot's rate commands
never time out: the killed run's last one would keep the gimbal turning); after a clean stop the next start
finds no marker.
"""
from __future__ import annotations

import signal
import time
from pathlib import Path

from tests.fault_rig import IDLE, TARGET, FaultRig, Feeder, Publisher


def test_sigkill_then_restart_comes_back_idle_and_says_so(tmp_path: Path) -> None:
    runtime = tmp_path / "run"
    runtime.mkdir()
    rig = FaultRig(tmp_path, "zenoh", env={"RUNTIME_DIRECTORY": str(runtime)}).start()
    camera = Publisher(rig)
    feeder = Feeder(camera).start()
    try:
        rig.meet_camera()
        first = rig.status()
        assert first["run"]["previous_exit"] == "clean_or_first"
        assert (runtime / "running").exists()
        rig.select(TARGET)
        killed_pid = rig.daemon.pid
        assert rig.daemon.process is not None
        rig.daemon.process.send_signal(signal.SIGKILL)
        assert rig.daemon.exited.wait(10.0)
        assert (runtime / "running").exists(), "the killed run's marker is gone"
        restarted_at = time.monotonic()
        gimbal = "GIMBAL_MANAGER_SET_PITCHYAW"
        rig.restart()  # what systemd does after RestartSec
        assert rig.sim is not None
        sample = rig.wait_track(lambda s: True, 60.0)
        assert sample is not None, rig.daemon.log_tail()
        assert sample["state"] == "idle" and sample["box_px"] is None, sample
        back_s = time.monotonic() - restarted_at
        status = rig.status()
        assert status["run"]["previous_exit"] == "unclean" and status["run"]["previous_pid"] == killed_pid
        assert status["track"]["state"] == "idle"
        lines = rig.log_lines(r"event=restarted_after_unclean_exit")
        assert len(lines) == 1 and f"previous_pid={killed_pid} " in lines[0] and "track=idle" in lines[0], lines
        assert rig.log_lines(r"event=started .* track=idle previous_exit=unclean")
        # the killed run's last gimbal rate is cancelled: zero rates once, then nothing (idle)
        assert rig.autopilot.from_service.wait_for(lambda: bool(rig.from_autopilot_view(gimbal, restarted_at)), 10.0)
        zeroed = [r.msg for r in rig.from_autopilot_view(gimbal, restarted_at)]
        assert len(zeroed) == 1 and (zeroed[0].yaw_rate, zeroed[0].pitch_rate) == (0.0, 0.0), zeroed
        assert rig.log_lines(r"event=gimbal_zeroed reason=previous_run_killed")
        rig.meet_camera()  # the ground station meets the camera again; its 275 says IDLE
        assert rig.wait_275(IDLE, time.monotonic(), 5.0) is not None
        # a clean stop removes the marker: the next start is not reported as a crash
        assert rig.daemon.stop() == 0
        assert not (runtime / "running").exists()
        rig.restart()
        assert rig.wait_track(lambda s: True, 60.0) is not None
        assert rig.status()["run"]["previous_exit"] == "clean_or_first"
        assert len(rig.log_lines(r"event=restarted_after_unclean_exit")) == 1
        assert len(rig.log_lines(r"event=gimbal_zeroed")) == 1
        print(f"\nSIGKILL while tracking, started again: tracking idle {back_s:.2f} s after the start "
              f"(log event=restarted_after_unclean_exit previous_pid={killed_pid}, status run.previous_exit unclean)")
    finally:
        feeder.close()
        code = rig.close()
    assert code == 0, rig.daemon.log_tail()
