"""The daemon (a process) against ArduCopter SITL, ArduPilot's own firmware (../shared/sitl, issue 46).

Each test runs its own SITL instance (sim.firmware.ArduPilotSitl: -I N, a temporary working directory,
its own UDP ports). The test is the ground station on SITL's SERIAL0; the daemon is the companion
computer on SERIAL1, through a wire tap that records what the daemon sends; camera frames (a target
held up and right of the image centre) come over Zenoh. The ground station's commands reach the camera
through ArduPilot's own routing."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")

from service.control.geo import GroundTarget  # noqa: E402
from service.mavlink.messages import follow_target  # noqa: E402
from sim.firmware import COPTER_BRAKE, COPTER_GUIDED, ArduPilotSitl, connect, euler_deg  # noqa: E402
from tests.firmware_peers import FRAME_SIZE, STOP_TRACKING, TARGET_PX, FirmwareRig, Station, WireTap  # noqa: E402

AUTOPILOT, CAMERA = (1, 1), (1, 100)
HFOV_DEG = 70.0  # config.yaml's camera.hfov_deg
GIMBAL_DEVICE_ATTITUDE_STATUS, GIMBAL_MANAGER_STATUS = 285, 281
COPTER_FOLLOW = 23


class Rig(FirmwareRig):
    """ArduCopter SITL + ground station + tap + camera frames + daemon, as one context."""

    name = "ArduPilot"

    def __init__(self, tmp_path: Path, overrides: dict[str, Any], speedup: float = 1.0, links: int = 2,
                 params: dict[str, float] | None = None) -> None:
        super().__init__(ArduPilotSitl(speedup=speedup, links=links, params=params), tmp_path, overrides, "apfw")
        self.autopilot, self.camera_id = AUTOPILOT, CAMERA

    def __enter__(self) -> "Rig":
        self.firmware.__enter__()
        self.gcs = Station(self.firmware.gcs_url).start()
        self.start_daemon()
        return self

    def mount(self) -> tuple[float, float]:
        """The mount's latest reported (pitch, yaw) in degrees (GIMBAL_DEVICE_ATTITUDE_STATUS)."""
        status = self.gcs.latest("GIMBAL_DEVICE_ATTITUDE_STATUS", AUTOPILOT)
        assert status is not None, "no GIMBAL_DEVICE_ATTITUDE_STATUS"
        _, pitch, yaw = euler_deg(status.q)
        return pitch, yaw

    def set_mode(self, custom_mode: int) -> None:
        """The pilot switches ArduCopter's flight mode (MAV_CMD_DO_SET_MODE) and the heartbeat shows it."""
        assert self.gcs.command(AUTOPILOT, 176, [1, custom_mode]).result == 0  # 176: DO_SET_MODE, 1: custom
        since = time.monotonic()
        assert self.gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                             and m.custom_mode == custom_mode, 5.0, since) is not None

    def position(self, after: float = 0.0) -> Any:
        """LOCAL_POSITION_NED at least `after` s from now."""
        since = time.monotonic() + after
        msg = self.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED", after + 5.0, since)
        assert msg is not None, "LOCAL_POSITION_NED stopped"
        return msg

    def settled_mount(self, timeout: float = 10.0) -> tuple[float, float]:
        """The mount's (pitch, yaw) deg once two reports 0.5 s apart agree within 0.2 deg (just after boot
        it reports 0, 0 before it moves to its start attitude)."""
        deadline = time.monotonic() + timeout
        before = self.mount_after(0.0)
        while time.monotonic() < deadline:
            after = self.mount_after(0.5)
            if abs(after[0] - before[0]) < 0.2 and abs(after[1] - before[1]) < 0.2:
                return after
            before = after
        raise AssertionError(f"mount still moving after {timeout} s")

    def rates_sent(self, since: float = 0.0) -> list[tuple[float, float]]:
        """(pitch_rate, yaw_rate) rad/s of every GIMBAL_MANAGER_SET_PITCHYAW the daemon sent since `since`."""
        return [(m.pitch_rate, m.yaw_rate) for m in self.tap.sent("GIMBAL_MANAGER_SET_PITCHYAW", since)]


def _no_angle_rate_mix(tap: WireTap) -> None:
    """Every gimbal message the daemon sent asks for rates or angles, never both (ArduPilot ignores a mix)."""
    for msg in tap.sent("GIMBAL_MANAGER_SET_PITCHYAW"):
        angles = [math.isfinite(msg.pitch), math.isfinite(msg.yaw)]
        rates = [math.isfinite(msg.pitch_rate), math.isfinite(msg.yaw_rate)]
        assert (all(rates) and not any(angles)) or (all(angles) and not any(rates)), msg
    for msg in tap.sent("GIMBAL_MANAGER_SET_ATTITUDE"):
        quaternion = any(math.isfinite(v) for v in msg.q)
        rates = any(math.isfinite(v) for v in (msg.angular_velocity_y, msg.angular_velocity_z))
        assert not (quaternion and rates), msg


pytestmark = pytest.mark.firmware("arducopter")  # real firmware processes, 10-30 s a test


def test_target_off_centre_turns_the_real_mount_towards_it_and_stop_and_loss_zero_the_rates(tmp_path: Path) -> None:
    with Rig(tmp_path, {"gimbal": {"backend": "ardupilot", "coast_s": 0.0}}) as rig:
        rig.stream_to_gcs(GIMBAL_DEVICE_ATTITUDE_STATUS, 20)
        rig.meet_camera()
        pitch0, yaw0 = rig.settled_mount()
        selected = rig.select()
        # rates of the right sign: the target is right of and above the centre -> yaw right, pitch up
        assert rig.tap.from_daemon.wait_for(lambda: len(rig.rates_sent(selected)) >= 5, 10.0), rig.diagnostics()
        first = rig.rates_sent(selected)[:5]
        assert all(pitch_rate > 0 and yaw_rate > 0 for pitch_rate, yaw_rate in first), first
        # ArduPilot's mount turns the same way (the image is held still: the target stays off centre)
        pitch1, yaw1 = rig.mount_after(0.8)
        assert yaw1 - yaw0 > 5.0 and pitch1 - pitch0 > 5.0, (pitch0, yaw0, pitch1, yaw1)

        # MAV_CMD_CAMERA_STOP_TRACKING: the last rates are zero and the mount stops where it is
        stopped = time.monotonic()  # before the command: the daemon may act on it before its ACK reaches us
        assert rig.gcs.command(CAMERA, STOP_TRACKING, [0]).result == 0
        assert rig.tap.from_daemon.wait_for(lambda: (0.0, 0.0) in rig.rates_sent(stopped), 3.0), rig.rates_sent(stopped)
        settled = rig.mount_after(0.5)
        still = rig.mount_after(1.5)
        assert abs(still[0] - settled[0]) < 0.5 and abs(still[1] - settled[1]) < 0.5, (settled, still)
        assert rig.rates_sent(stopped)[-1] == (0.0, 0.0)

        # loss: the target leaves the view while tracking; with coast_s 0 the rates go to zero at once
        reselected = rig.select()
        assert rig.tap.from_daemon.wait_for(lambda: any(p > 0 for p, _ in rig.rates_sent(reselected)), 5.0)
        rig.camera.visible = False
        gone = time.monotonic()
        assert rig.tap.from_daemon.wait_for(lambda: (0.0, 0.0) in rig.rates_sent(gone), 5.0), rig.diagnostics()
        zero_from = next(t.at for t in rig.tap.from_daemon.of("GIMBAL_MANAGER_SET_PITCHYAW")
                         if t.at >= gone and (t.msg.pitch_rate, t.msg.yaw_rate) == (0.0, 0.0))
        held = rig.mount_after(0.5)
        still = rig.mount_after(1.5)
        assert abs(still[0] - held[0]) < 0.5 and abs(still[1] - held[1]) < 0.5, (held, still)
        assert all(rates == (0.0, 0.0) for rates in rig.rates_sent(zero_from)), "rates resumed while the target is gone"
        _no_angle_rate_mix(rig.tap)


def _bearing_to_target_deg() -> float:
    """The target's bearing right of the camera's axis (deg): TARGET_PX with FRAME_SIZE and HFOV_DEG."""
    focal_px = FRAME_SIZE[0] / 2 / math.tan(math.radians(HFOV_DEG / 2))
    return math.degrees(math.atan((TARGET_PX[0] - FRAME_SIZE[0] / 2) / focal_px))


def test_velocity_guidance_in_guided_only_moves_towards_the_target_and_holds_on_loss_and_follow_ignores_the_camera(
        tmp_path: Path) -> None:
    overrides = {"gimbal": {"backend": "none", "coast_s": 0.0},  # the mount stays where ArduPilot holds it
                 "guidance": {"mode": "velocity", "yaw_gain": 0.2, "follow_distance_m": 5.0}}
    # FOLLOW set up for the end of the test: a fixed offset 5 m south of the target (a zero offset would be
    # taken from where the vehicle is when FOLLOW starts, and it would not move)
    follow = {"FOLL_ENABLE": 1, "FOLL_SYSID": 0, "FOLL_OFS_TYPE": 0, "FOLL_OFS_X": -5}
    with Rig(tmp_path, overrides, speedup=10, links=3, params=follow) as rig:
        # the pilot: GUIDED, arm, take off to 10 m at 10 x real time (the 30-40 s position-estimate wait
        # takes a few seconds), then real time for the daemon
        pilot = connect(rig.firmware.extra_urls[0])
        try:
            rig.firmware.wait_heartbeat(pilot)
            rig.firmware.arm_takeoff(pilot, altitude_m=10.0, timeout=60.0)
            rig.firmware.set_speedup(pilot, 1)
        finally:
            pilot.close()
        rig.stream_to_gcs(32, 10)  # LOCAL_POSITION_NED
        rig.stream_to_gcs(30, 10)  # ATTITUDE
        rig.meet_camera()
        # outside GUIDED nothing goes out: BRAKE (holds without RC input, unlike LOITER, which descends at
        # SITL's default throttle), tracking, no setpoint
        rig.set_mode(COPTER_BRAKE)
        selected = rig.select()
        assert rig.tap.from_daemon.wait_for(lambda: bool(rig.setpoints(selected)), 2.0) is False, \
            rig.setpoints(selected)
        # GUIDED: setpoints turn it right towards the target and move it forward
        yaw0 = math.degrees(rig.gcs.latest("ATTITUDE", AUTOPILOT).yaw)
        start = rig.position()
        rig.set_mode(COPTER_GUIDED)
        guided = time.monotonic()
        assert rig.tap.from_daemon.wait_for(lambda: len(rig.setpoints(guided)) >= 5, 5.0), rig.diagnostics()
        setpoint = rig.setpoints(guided)[-1]
        assert setpoint.vx > 0.5 and setpoint.yaw_rate > 0, setpoint  # body frame: forward, turning right
        moved = rig.position(after=3.0)
        towards = math.radians(yaw0 + _bearing_to_target_deg())
        along = (moved.x - start.x) * math.cos(towards) + (moved.y - start.y) * math.sin(towards)
        across = -(moved.x - start.x) * math.sin(towards) + (moved.y - start.y) * math.cos(towards)
        assert along > 2.0 and abs(across) < along, (along, across, start, moved)
        assert abs(moved.z - start.z) < 1.0, (start.z, moved.z)  # vz 0: it keeps its height
        assert math.degrees(rig.gcs.latest("ATTITUDE", AUTOPILOT).yaw) - yaw0 > 2.0  # turned right

        # the target leaves the view: the daemon's setpoints become zero velocity and the vehicle holds
        rig.camera.visible = False
        gone = time.monotonic()
        assert rig.tap.from_daemon.wait_for(
            lambda: any(m.vx == 0 and m.vy == 0 and m.yaw_rate == 0 for m in rig.setpoints(gone)), 3.0)
        held = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) < 0.3, 8.0, gone)
        assert held is not None, "vehicle did not stop after the loss"

        # the setpoints stop altogether (the companion computer dies mid-move): ArduPilot's GUID_TIMEOUT
        # (3 s) stops the vehicle, which stays in GUIDED
        rig.camera.visible = True
        reselected = rig.select()
        assert rig.tap.from_daemon.wait_for(lambda: any(m.vx > 0.5 for m in rig.setpoints(reselected)), 5.0)
        moving = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) > 1.0,
                              8.0, reselected)
        assert moving is not None, "vehicle did not move again"
        rig.daemon.process.kill()
        killed = time.monotonic()
        rig.daemon.process.wait(5.0)
        assert rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) > 0.5,
                            2.0, killed + 1.5) is not None, "stopped before GUID_TIMEOUT"
        stopped = rig.gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED" and math.hypot(m.vx, m.vy) < 0.3,
                               10.0, killed)
        assert stopped is not None, "GUID_TIMEOUT did not stop the vehicle"
        beat = rig.gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1, 3.0,
                            time.monotonic())
        assert beat.custom_mode == COPTER_GUIDED

        # FOLLOW (guidance.mode follow_target): ArduPilot ignores FOLLOW_TARGET from its own system id, the
        # camera's, and follows the same message from another system. The daemon's own message (its
        # builder), 20 m north of the vehicle, sent as the camera (1/100) and then as system 7
        rig.stream_to_gcs(33, 10)  # GLOBAL_POSITION_INT
        here = rig.gcs.latest("GLOBAL_POSITION_INT", AUTOPILOT)
        target = GroundTarget(here.lat / 1e7 + 20.0 / 111_111.0, here.lon / 1e7, here.alt / 1000.0, 20.0, 0.0)
        rig.set_mode(COPTER_FOLLOW)
        moved = {}
        for identity in (CAMERA, (7, 100)):
            sender = Station(rig.firmware.extra_urls[0], *identity).start()
            try:
                assert sender.wait(lambda m: m.get_type() == "HEARTBEAT", 5.0) is not None
                before = rig.position()
                end = time.monotonic() + 4.0
                while time.monotonic() < end:  # at 10 Hz, as the daemon's guidance.rate_hz
                    sender.send(lambda mav: follow_target(mav, int(time.monotonic() * 1000) & 0xFFFFFFFF, target))
                    sender.wait(lambda m: False, 0.1)
                after = rig.position()
            finally:
                sender.close()
            moved[identity] = after.x - before.x
        assert abs(moved[CAMERA]) < 0.5 and moved[(7, 100)] > 3.0, moved


def test_gimbal_manager_handshake_as_ardupilot_does_it(tmp_path: Path) -> None:
    """ArduPilot records who is primary control (GIMBAL_MANAGER_STATUS) but does not enforce it: any
    sender's rates move the mount. The daemon claims control for a track (1001), yields when a ground
    station takes it (one zero rate, then silence: ArduPilot's rate commands have no time-out), claims
    again when it is released, and after a reboot (which forgets the owner and the requested streams)."""
    with Rig(tmp_path, {"gimbal": {"backend": "ardupilot"}}, links=3) as rig:
        status = rig.stream_to_gcs(GIMBAL_MANAGER_STATUS, 5)
        assert (status.primary_control_sysid, status.primary_control_compid) == (0, 0)  # nobody at boot
        rig.stream_to_gcs(GIMBAL_DEVICE_ATTITUDE_STATUS, 20)
        rig.meet_camera()
        rig.settled_mount()

        def primary_becomes(who: tuple[int, int], since: float, timeout: float = 5.0) -> bool:
            status = rig.gcs.wait(lambda m: m.get_type() == "GIMBAL_MANAGER_STATUS"
                                  and (m.primary_control_sysid, m.primary_control_compid) == who, timeout, since)
            return status is not None

        selected = rig.select()
        assert primary_becomes(CAMERA, selected), f"the daemon did not claim\n{rig.diagnostics()}"

        # a ground station takes control: ArduPilot accepts it and names it; the daemon stops commanding
        taken_at = time.monotonic()
        assert rig.gcs.command(AUTOPILOT, 1001, [255, 190, -1, -1]).result == 0
        assert primary_becomes((255, 190), taken_at)
        assert rig.tap.from_daemon.wait_for(lambda: (0.0, 0.0) in rig.rates_sent(taken_at), 3.0), rig.diagnostics()
        quiet_from = time.monotonic()
        held = rig.mount_after(0.3)
        assert rig.gcs.wait(lambda m: False, 2.0) is None  # two seconds of the ground station in control
        assert rig.rates_sent(quiet_from) == [] and not [m for m in rig.tap.sent("COMMAND_LONG", quiet_from)
                                                          if m.command == 1001], "the daemon fought the ground station"
        still = rig.mount()
        assert abs(still[0] - held[0]) < 0.5 and abs(still[1] - held[1]) < 0.5, (held, still)
        # not enforced: a third component's rates move the mount while the ground station is primary
        other = Station(rig.firmware.extra_urls[0], 2, 191).start()  # a second ground station, on SERIAL2
        try:
            # udpin answers only a peer it has heard: wait for ArduPilot's heartbeat on that link first
            assert other.wait(lambda m: m.get_type() == "HEARTBEAT", 5.0) is not None
            other.send(lambda mav: mav.gimbal_manager_set_pitchyaw_encode(1, 1, 0, 0, math.nan, math.nan, 0.0, 0.5))
            moved = rig.mount_after(1.0)
            other.send(lambda mav: mav.gimbal_manager_set_pitchyaw_encode(1, 1, 0, 0, math.nan, math.nan, 0.0, 0.0))
        finally:
            other.close()
        assert abs(moved[1] - still[1]) > 5.0, (still, moved)
        assert (rig.gcs.latest("GIMBAL_MANAGER_STATUS").primary_control_sysid,
                rig.gcs.latest("GIMBAL_MANAGER_STATUS").primary_control_compid) == (255, 190)

        # the ground station releases control: the daemon claims it back and its rates resume
        released = time.monotonic()
        assert rig.gcs.command(AUTOPILOT, 1001, [-3, -3, -1, -1]).result == 0
        assert primary_becomes(CAMERA, released), rig.diagnostics()
        assert rig.tap.from_daemon.wait_for(lambda: any(p > 0 for p, _ in rig.rates_sent(released)), 3.0)

        # an autopilot reboot: ArduPilot forgets the primary controller (0, 0) and every requested stream;
        # the daemon asks for its streams again, sees nobody in control and claims again
        rebooted = time.monotonic()
        assert rig.gcs.command(AUTOPILOT, 246, [1]).result == 0  # MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
        assert rig.gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1, 15.0,
                            rebooted + 0.5) is not None
        status = rig.stream_to_gcs(GIMBAL_MANAGER_STATUS, 5)  # the ground station asks again for its own
        assert primary_becomes(CAMERA, rebooted, timeout=15.0), f"no claim after the reboot\n{rig.diagnostics()}"
        after_claim = time.monotonic()
        claims = [m for m in rig.tap.sent("COMMAND_LONG", rebooted) if m.command == 1001]
        assert claims and (claims[-1].param1, claims[-1].param2) == CAMERA
        rig.stream_to_gcs(GIMBAL_DEVICE_ATTITUDE_STATUS, 20)
        start = rig.mount_after(0.0)
        end = rig.mount_after(0.8)
        assert end[1] - start[1] > 3.0, (start, end)  # the rates move the rebooted mount again
        assert rig.rates_sent(after_claim), "no rates after the reboot"
        _no_angle_rate_mix(rig.tap)
