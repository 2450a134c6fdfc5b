"""The daemon (a process) against PX4 SITL with SIH, PX4's own firmware (../shared/sitl/px4, issue 46).

Each test runs its own PX4 instance (sim.firmware.Px4Sih: -i N, a temporary working directory, its own
UDP ports; MNT_MODE_IN 4 / MNT_MODE_OUT 0: the gimbal manager v2 without a gimbal device, whose reported
attitude is the commanded one; no logging). The test is the ground station on PX4's GCS link; the
daemon is the companion computer on its onboard link, through a wire tap that records what the daemon
sends; camera frames (a target held up and right of the image centre) come over Zenoh. PX4 forwards
between its links (`mavlink start -f`), so the ground station's commands reach the camera."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")

from sim.firmware import PX4_MAIN_OFFBOARD, PX4_MAIN_POSCTL, Px4Sih, connect, euler_deg, px4_main_mode  # noqa: E402
from tests.firmware_peers import STOP_TRACKING, FirmwareRig, Station  # noqa: E402

GIMBAL_DEVICE_ATTITUDE_STATUS, GIMBAL_MANAGER_STATUS = 285, 281


class Px4Rig(FirmwareRig):
    """PX4 SIH + ground station + tap + camera frames + daemon, as one context. `before_daemon(firmware)`
    runs with the firmware up and nothing else on its GCS port (a pilot's takeoff on a plain connection)."""

    name = "PX4"

    def __init__(self, tmp_path: Path, overrides: dict[str, Any], before_daemon: Any = None) -> None:
        super().__init__(Px4Sih(), tmp_path, overrides, "px4fw")
        self.before_daemon = before_daemon

    def __enter__(self) -> "Px4Rig":
        self.firmware.__enter__()
        self.autopilot = (self.firmware.system_id, 1)
        self.camera_id = (self.firmware.system_id, 100)
        if self.before_daemon is not None:
            self.before_daemon(self.firmware)
        self.gcs = Station(self.firmware.gcs_url).start()
        # PX4 boots in ~5 s; udpin sends nothing before it has heard the peer
        if self.heartbeat(0.0, timeout=60.0) is None:
            raise AssertionError(f"no PX4 heartbeat\n{self.firmware.log_tail()}")
        self.start_daemon()
        return self

    def primary_becomes(self, who: tuple[int, int], since: float, timeout: float = 5.0) -> bool:
        return self.gcs.wait(lambda m: m.get_type() == "GIMBAL_MANAGER_STATUS"
                             and (m.primary_control_sysid, m.primary_control_compid) == who, timeout, since) is not None

    def rates_sent(self, since: float = 0.0) -> list[tuple[float, float]]:
        """(pitch, yaw) angular velocity rad/s of every GIMBAL_MANAGER_SET_ATTITUDE the daemon sent since `since`."""
        return [(m.angular_velocity_y, m.angular_velocity_z)
                for m in self.tap.sent("GIMBAL_MANAGER_SET_ATTITUDE", since)]

    def heartbeat(self, since: float, condition: Any = lambda m: True, timeout: float = 5.0) -> Any:
        return self.gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and (m.get_srcSystem(), m.get_srcComponent())
                             == self.autopilot and condition(m), timeout, since)


pytestmark = pytest.mark.firmware("px4")  # real firmware processes, 10-30 s a test


def test_gimbal_claim_and_282_rates_move_the_px4_gimbal_and_stop_zeroes_them(tmp_path: Path) -> None:
    with Px4Rig(tmp_path, {"gimbal": {"backend": "px4"}}) as rig:
        status = rig.stream_to_gcs(GIMBAL_MANAGER_STATUS, 5)
        assert (status.primary_control_sysid, status.primary_control_compid) == (0, 0)  # nobody at boot
        rig.stream_to_gcs(GIMBAL_DEVICE_ATTITUDE_STATUS, 20)
        rig.meet_camera()
        pitch0, yaw0 = rig.mount_after(0.0)
        selected = rig.select()
        # the claim (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 1001) makes the camera primary; then 282 rates
        assert rig.primary_becomes(rig.camera_id, selected), rig.diagnostics()
        claims = [m for m in rig.tap.sent("COMMAND_LONG", selected) if m.command == 1001]
        assert claims and (claims[0].param1, claims[0].param2) == rig.camera_id
        assert rig.tap.from_daemon.wait_for(lambda: len(rig.rates_sent(selected)) >= 5, 5.0), rig.diagnostics()
        assert all(p > 0 and y > 0 for p, y in rig.rates_sent(selected)[:5])  # up and right, towards the target
        for msg in rig.tap.sent("GIMBAL_MANAGER_SET_ATTITUDE"):
            assert all(math.isnan(v) for v in msg.q), msg  # rates only, never a quaternion with them
        assert not rig.tap.sent("GIMBAL_MANAGER_SET_PITCHYAW"), "287: PX4 does not take it from outside"
        pitch1, yaw1 = rig.mount_after(0.8)
        assert yaw1 - yaw0 > 5.0 and pitch1 - pitch0 > 5.0, (pitch0, yaw0, pitch1, yaw1)

        stopped = time.monotonic()  # before the command: the daemon may act on it before its ACK reaches us
        assert rig.gcs.command(rig.camera_id, STOP_TRACKING, [0]).result == 0
        assert rig.tap.from_daemon.wait_for(lambda: (0.0, 0.0) in rig.rates_sent(stopped), 3.0), rig.rates_sent(stopped)
        settled = rig.mount_after(0.3)
        still = rig.mount_after(1.3)
        assert abs(still[0] - settled[0]) < 0.5 and abs(still[1] - settled[1]) < 0.5, (settled, still)

        # a ground station takes control: PX4 names it; the daemon stops and does not claim back
        reselected = rig.select()
        assert rig.tap.from_daemon.wait_for(lambda: any(p > 0 for p, _ in rig.rates_sent(reselected)), 5.0)
        taken = time.monotonic()
        assert rig.gcs.command(rig.autopilot, 1001, [255, 190, -1, -1]).result == 0
        assert rig.primary_becomes((255, 190), taken)
        assert rig.gcs.wait(lambda m: m.get_type() == "GIMBAL_MANAGER_STATUS", 2.0, time.monotonic() + 1.0)
        quiet = time.monotonic()
        assert rig.gcs.wait(lambda m: False, 2.0) is None
        assert not rig.rates_sent(quiet) and not [m for m in rig.tap.sent("COMMAND_LONG", quiet) if m.command == 1001]
        assert (rig.gcs.latest("GIMBAL_MANAGER_STATUS").primary_control_sysid,
                rig.gcs.latest("GIMBAL_MANAGER_STATUS").primary_control_compid) == (255, 190)


def _bearing_to_target_deg() -> float:
    from tests.test_firmware_ardupilot import _bearing_to_target_deg as bearing

    return bearing()


def test_offboard_velocity_guidance_after_the_setpoint_stream_and_px4s_failsafe_when_it_stops(tmp_path: Path) -> None:
    def take_off(firmware: Px4Sih) -> None:
        pilot = connect(firmware.gcs_url)
        try:
            firmware.wait_heartbeat(pilot, 60.0)
            firmware.arm_takeoff(pilot, altitude_m=6.0, timeout=90.0)  # PX4 climbs at ~1 m/s: low saves time
        finally:
            pilot.close()

    overrides = {"gimbal": {"backend": "none", "coast_s": 0.0},
                 "guidance": {"mode": "velocity", "yaw_gain": 0.2, "follow_distance_m": 2.0}}
    with Px4Rig(tmp_path, overrides, before_daemon=take_off) as rig:
        # the pilot points the gimbal 45 deg down (its own claim, then a release) so that the camera sees ground
        rig.stream_to_gcs(GIMBAL_MANAGER_STATUS, 5)
        claimed = time.monotonic()
        assert rig.gcs.command(rig.autopilot, 1001, [255, 190, -1, -1]).result == 0
        assert rig.primary_becomes((255, 190), claimed)
        assert rig.gcs.command(rig.autopilot, 1000, [-45, 0, math.nan, math.nan, 0]).result == 0
        rig.stream_to_gcs(GIMBAL_DEVICE_ATTITUDE_STATUS, 10)
        assert rig.gcs.wait(lambda m: m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS" and euler_deg(m.q)[1] < -40,
                            5.0) is not None
        released = time.monotonic()
        assert rig.gcs.command(rig.autopilot, 1001, [0, 0, -1, -1]).result == 0
        assert rig.primary_becomes((0, 0), released)
        rig.meet_camera()
        assert px4_main_mode(rig.heartbeat(time.monotonic()).custom_mode) == 4  # AUTO (LOITER after takeoff)
        selected = rig.select()
        # outside OFFBOARD the daemon streams zero velocity only (PX4 needs a stream before the switch)
        assert rig.tap.from_daemon.wait_for(lambda: len(rig.setpoints(selected)) >= 15, 5.0), rig.diagnostics()
        assert all(m.vx == 0 and m.vy == 0 and m.vz == 0 and m.yaw_rate == 0 for m in rig.setpoints(selected))
        yaw0 = math.degrees(rig.gcs.latest("ATTITUDE", rig.autopilot).yaw)
        start = rig.gcs.latest("LOCAL_POSITION_NED", rig.autopilot)
        switched = time.monotonic()
        assert rig.gcs.command(rig.autopilot, 176, [1, PX4_MAIN_OFFBOARD]).result == 0  # the pilot: OFFBOARD
        assert rig.heartbeat(switched, lambda m: px4_main_mode(m.custom_mode) == PX4_MAIN_OFFBOARD) is not None, \
            [m.text for _, m in rig.gcs.of("STATUSTEXT", selected)]
        assert rig.tap.from_daemon.wait_for(lambda: any(m.vx > 0.5 for m in rig.setpoints(switched)), 5.0)
        moved_at = time.monotonic() + 3.0
        moved = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED", 5.0, moved_at)
        towards = math.radians(yaw0 + _bearing_to_target_deg())
        along = (moved.x - start.x) * math.cos(towards) + (moved.y - start.y) * math.sin(towards)
        across = -(moved.x - start.x) * math.sin(towards) + (moved.y - start.y) * math.cos(towards)
        assert along > 2.0 and abs(across) < along, (along, across)

        # the target leaves the view: zero velocity keeps streaming, PX4 stays in OFFBOARD and holds
        rig.camera.visible = False
        gone = time.monotonic()
        held = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) < 0.3, 8.0, gone)
        assert held is not None, "vehicle did not stop after the loss"
        assert px4_main_mode(rig.heartbeat(time.monotonic()).custom_mode) == PX4_MAIN_OFFBOARD

        # the setpoint stream stops (the companion computer dies mid-move): PX4's offboard-loss failsafe
        # (COM_OF_LOSS_T 1 s, then COM_OBL_RC_ACT 0) leaves OFFBOARD for POSCTL ("Failsafe activated") about
        # 1 s later, and the vehicle stops there
        rig.camera.visible = True
        reselected = rig.select()
        assert rig.tap.from_daemon.wait_for(lambda: any(m.vx > 0.5 for m in rig.setpoints(reselected)), 5.0)
        moving = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) > 0.8,
                              10.0, reselected)
        assert moving is not None, (
            "vehicle did not move again: max speed "
            f"{max(math.hypot(m.vx, m.vy) for _, m in rig.gcs.of('LOCAL_POSITION_NED', reselected)):.2f} m/s, "
            f"setpoints {[(round(m.vx, 2), round(m.yaw_rate, 2)) for m in rig.setpoints(reselected)][-5:]}, "
            f"mode {hex(rig.heartbeat(time.monotonic()).custom_mode)}, "
            f"z {rig.gcs.latest('LOCAL_POSITION_NED', rig.autopilot).z:.1f}")
        rig.daemon.process.kill()
        killed = time.monotonic()
        rig.daemon.process.wait(5.0)
        assert px4_main_mode(rig.heartbeat(killed).custom_mode) == PX4_MAIN_OFFBOARD  # not at once
        left = rig.heartbeat(killed, lambda m: px4_main_mode(m.custom_mode) != PX4_MAIN_OFFBOARD, timeout=10.0)
        assert left is not None, "PX4 stayed in OFFBOARD without setpoints"
        left_after = next(at for at, m in rig.gcs.of("HEARTBEAT", killed) if m is left) - killed
        assert 0.5 < left_after < 3.0, left_after
        assert px4_main_mode(left.custom_mode) == PX4_MAIN_POSCTL, hex(left.custom_mode)
        assert any("Failsafe" in m.text for _, m in rig.gcs.of("STATUSTEXT", killed))
        assert rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) < 0.3,
                            10.0, killed) is not None, "no hold after the failsafe"
        assert left.base_mode & 128  # still armed, flying
