"""Loop decisions -> MAVLink messages: the gimbal backend (ardupilot / px4 / none) and guidance.

Guidance is gated on the autopilot's heartbeat (alive, GUIDED / OFFBOARD) and throttled to
guidance.rate_hz on the frames' capture clock (see `_due`); velocity mode commands zero velocity while the track is lost and once when it
stops. With PX4 outside OFFBOARD, zero-velocity setpoints stream while tracking, because PX4 only
lets the pilot engage OFFBOARD while a setpoint stream exists (and ignores it in other modes). follow_target sends FOLLOW_TARGET only while there is a ground estimate of a tracked target
(when it stops, the autopilot's follow timeout holds the vehicle). Never arms, never changes modes.
Once the autopilot has been heard, nothing at all goes out while its heartbeat is lost (older than
mavlink.heartbeat_timeout_s): gimbal rates, claims and guidance are held (counted as `held`, logged
once as event=commands_held) and resume with the next command after the heartbeat returns
(event=commands_resumed).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20.common import MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4, MAV_COMP_ID_AUTOPILOT1

from service.config import ServiceConfig
from service.control.guidance import ZERO_VELOCITY, guidance_allowed, velocity_setpoint
from service.domain import ControlCommand, LoopState
from service.mavlink import messages
from service.mavlink.autopilot import AutopilotView

log = logging.getLogger("service.control")


@dataclass(frozen=True)
class GimbalControl:
    """What the gimbal backend does for one command: send the rates, claim primary control (1001), or
    yield (a ground station took control from us: stop commanding until the next track)."""

    send: bool
    claim: bool
    yields: bool = False


def gimbal_control(backend: str, primary: tuple[int, int] | None, own: tuple[int, int], taken: bool) -> GimbalControl:
    """The gimbal manager handshake (MAVLink gimbal protocol v2) for one command.

    primary: who GIMBAL_MANAGER_STATUS names in control (None: never heard); own: our (sysid, compid);
    taken: that controller took control during the current track, after we had it or had claimed it.
    In control: send. Nobody in control (0, 0: at boot, after a reboot or a release): claim. Someone else
    in control: claim when they had it before (the operator's track command asks this camera to point
    the gimbal), yield when they took it from us (a ground station taking control wins). ArduPilot records primary control
    but does not enforce it, and a rate command has no time-out there, so the ardupilot backend sends its
    rates unless it yields, and also without any manager status; PX4 honours only the primary controller.
    """
    if primary == own:
        return GimbalControl(send=True, claim=False)
    if primary is None:
        return GimbalControl(send=backend == "ardupilot", claim=backend == "px4")
    if primary != (0, 0) and taken:
        return GimbalControl(send=False, claim=False, yields=True)
    return GimbalControl(send=backend == "ardupilot", claim=True)


class MavlinkOutputs:
    """Implements loop.Outputs over a link (`send(msg)`, `mav`, `system_id`)."""

    def __init__(self, config: ServiceConfig, link: object, autopilot: Callable[[], AutopilotView],
                 time_boot_ms: Callable[[], int]) -> None:
        self.config = config
        self.link = link
        self.autopilot = autopilot
        self.time_boot_ms = time_boot_ms
        self._last_claim_s: float | None = None
        self._last_guidance_frame_s: float | None = None  # capture time of the last guidance frame
        self._guidance_was_allowed = False
        self._follow_warned = False  # the follow_target-with-ArduPilot warning is logged once
        self._was_tracking = False  # the previous gimbal command was for a track (a new track resets the next two)
        self._had_control = False  # GIMBAL_MANAGER_STATUS named us primary during the current track
        self._claimed_over: tuple[int, int] | None = None  # who was primary when we last claimed in this track
        self._yielded_to: tuple[int, int] | None = None  # who took gimbal control from us during this track
        self.counters = {"gimbal": 0, "claims": 0, "velocity": 0, "follow_target": 0, "gated": 0, "px4_prestream": 0,
                         "held": 0}
        self._held_since: float | None = None  # time.monotonic() s of the first command held in this silence
        # after a killed run: zero gimbal rates once the autopilot is heard (ArduPilot's rate commands never time
        # out, so the killed run's last rate would turn the gimbal until someone sends another)
        self.stop_gimbal_first = False

    def apply(self, now_s: float, command: ControlCommand) -> None:
        """Send what `command` asks for; now_s: time.monotonic(), for heartbeat age and gimbal claims."""
        view = self.autopilot()
        system_id = view.system_id or self.config.mavlink.system_id
        if not system_id:
            return  # no autopilot heard and none configured: nobody to command yet
        if self._hold_while_silent(now_s, view, command):
            return
        target = (system_id, MAV_COMP_ID_AUTOPILOT1)
        if self.stop_gimbal_first and view.alive(now_s, self.config.mavlink.heartbeat_timeout_s):
            self._stop_gimbal_after_unclean_exit(target)
        # guidance first, the gimbal command last: whoever sees a frame's gimbal command (a lockstep
        # simulator stepping its model on it) has its setpoint too; on a real link the order of two
        # messages sent microseconds apart does not matter
        mode = self.config.guidance.mode
        if mode == "velocity":
            self._velocity(now_s, view, target, command)
        elif mode == "follow_target":
            self._follow(command)
        if command.rates is not None:
            self._gimbal(now_s, view, target, command.rates, tracking=command.state != LoopState.IDLE)

    def _hold_while_silent(self, now_s: float, view: AutopilotView, command: ControlCommand) -> bool:
        """True (the command is held, not sent) while an autopilot heard before is silent: a rate or a
        setpoint sent into a dead link is either lost or, worse, acted on late when it comes back, and an
        open loop's commands are stale by then. Logs the start and the end of each hold once."""
        silent = view.last_heartbeat_s is not None and not view.alive(now_s, self.config.mavlink.heartbeat_timeout_s)
        if silent:
            if self._held_since is None:
                self._held_since = now_s
                log.warning("event=commands_held reason=autopilot_heartbeat_lost timeout_s=%.1f state=%s "
                            "detail=\"no gimbal or guidance command is sent until its heartbeat returns\"",
                            self.config.mavlink.heartbeat_timeout_s, command.state)
            self.counters["held"] += 1
            return True
        if self._held_since is not None:
            log.info("event=commands_resumed held_s=%.2f held=%d state=%s", now_s - self._held_since,
                     self.counters["held"], command.state)
            self._held_since = None
        return False

    def _stop_gimbal_after_unclean_exit(self, target: tuple[int, int]) -> None:
        """Zero gimbal rates once, the first time the autopilot is heard after a killed run (service.run_marker)."""
        self.stop_gimbal_first = False
        backend, mav = self.config.gimbal.backend, self.link.mav  # type: ignore[attr-defined]
        if backend not in ("ardupilot", "px4"):
            return
        build = messages.gimbal_rates_ardupilot if backend == "ardupilot" else messages.gimbal_rates_px4
        log.warning("event=gimbal_zeroed reason=previous_run_killed detail=\"the killed run's last rate command may "
                    "still be turning the gimbal (ArduPilot's do not time out): zero rates sent once\"")
        self.link.send(build(mav, target, self.config.gimbal.device_id, 0.0, 0.0))  # type: ignore[attr-defined]
        self.counters["gimbal"] += 1

    # --- gimbal -------------------------------------------------------------------------------
    def _gimbal(self, now_s: float, view: AutopilotView, target: tuple[int, int], rates: tuple[float, float],
                tracking: bool) -> None:
        backend, gimbal = self.config.gimbal.backend, self.config.gimbal
        if backend not in ("ardupilot", "px4"):
            return
        own = (self.link.system_id, self.config.mavlink.component_id)  # type: ignore[attr-defined]
        if tracking and not self._was_tracking:  # a new track: the operator asked this camera to point the gimbal
            self._had_control, self._yielded_to, self._claimed_over = False, None, None
        self._was_tracking = tracking
        if self._yielded_to is not None:
            if view.gimbal_primary not in (self._yielded_to, own):
                self._yielded_to = None  # released (0, 0) or passed on: ask again below
            else:
                return
        primary = view.gimbal_primary
        if primary == own:
            self._had_control = True
        # someone else than who held it when we claimed (our status stream is slower than a ground station's
        # claim: we may never have seen ourselves in control before it was taken)
        taken = primary not in (None, (0, 0), own) and (
            self._had_control or (self._claimed_over is not None and primary != self._claimed_over))
        control = gimbal_control(backend, primary, own, taken)
        yaw_rate, pitch_rate = rates
        mav = self.link.mav  # type: ignore[attr-defined]
        if control.yields:
            self._yielded_to = view.gimbal_primary
            log.warning("event=gimbal_control_taken by=%s/%s detail=\"gimbal commands stop until the next track or "
                        "a release\"", *view.gimbal_primary)  # type: ignore[misc]
            if backend == "ardupilot":  # its rate commands have no time-out: stop what we started
                self.link.send(messages.gimbal_rates_ardupilot(mav, target, gimbal.device_id, 0.0, 0.0))  # type: ignore[attr-defined]
                self.counters["gimbal"] += 1
            return
        # the claim is a handshake with the autopilot (it answers in real time): service clock
        if control.claim and tracking and (self._last_claim_s is None or now_s - self._last_claim_s >= gimbal.claim_interval_s):
            self.link.send(messages.gimbal_claim_px4(mav, target, own, gimbal.device_id))  # type: ignore[attr-defined]
            self._last_claim_s = now_s
            self._claimed_over = view.gimbal_primary
            self.counters["claims"] += 1
            log.info("event=gimbal_claim primary=%s", view.gimbal_primary)
        if not control.send:
            return
        if backend == "ardupilot":
            self.link.send(messages.gimbal_rates_ardupilot(mav, target, gimbal.device_id, yaw_rate, pitch_rate))  # type: ignore[attr-defined]
        else:
            self.link.send(messages.gimbal_rates_px4(mav, target, gimbal.device_id, yaw_rate, pitch_rate))  # type: ignore[attr-defined]
        self.counters["gimbal"] += 1

    # --- guidance -----------------------------------------------------------------------------
    def _due(self, command: ControlCommand, force: bool) -> bool:
        """Whether a guidance message goes out for this command: at most guidance.rate_hz of capture time.

        The throttle runs on the frames' capture clock, like the controllers: which frames' setpoints
        reach the autopilot then depends on the frames only (a lockstep simulation is reproducible;
        with a camera the capture clock is real time, so the rate on the link is the same). Commands
        not tied to a frame (hold after a frame gap, stop) are rare and always due. A capture time
        earlier than the last one sent (clock stepped back, stream restarted) re-anchors the throttle
        instead of silencing guidance until the clock catches up.
        """
        stamp = command.frame_time_s
        if stamp is None:
            self._last_guidance_frame_s = None
            return True
        period = 1.0 / self.config.guidance.rate_hz
        last = self._last_guidance_frame_s
        # 5 % slack: a frame stamped a hair early (camera jitter) must not halve the rate
        if force or last is None or stamp < last or stamp - last >= 0.95 * period:
            self._last_guidance_frame_s = stamp
            return True
        return False

    def _velocity(self, now_s: float, view: AutopilotView, target: tuple[int, int], command: ControlCommand) -> None:
        alive = view.alive(now_s, self.config.mavlink.heartbeat_timeout_s)
        allowed = alive and guidance_allowed(view.autopilot or 0, view.vehicle_type or 0, view.custom_mode or 0)
        if allowed != self._guidance_was_allowed:
            log.info("event=guidance_gate allowed=%s alive=%s custom_mode=%s", allowed, alive, view.custom_mode)
            self._guidance_was_allowed = allowed
        if not allowed:
            if command.state == LoopState.IDLE and not command.stopped:
                return
            self.counters["gated"] += 1
            if alive and view.autopilot == MAV_AUTOPILOT_PX4 and self._due(command, force=False):
                # PX4 lets the pilot engage OFFBOARD only while setpoints already stream (> 2 Hz, ~1 s).
                # Outside OFFBOARD it ignores them; zero velocity means "hold" the moment OFFBOARD starts,
                # and real setpoints follow once the heartbeat reports OFFBOARD.
                self.link.send(messages.velocity_target(self.link.mav, target, self.time_boot_ms(), ZERO_VELOCITY))  # type: ignore[attr-defined]
                self.counters["px4_prestream"] += 1
            return
        if command.state == LoopState.IDLE and not command.stopped:
            return
        if not self._due(command, force=command.stopped):
            return
        if command.state in (LoopState.TRACKING, LoopState.RECOVERED) and command.bearing is not None:
            ground_range = command.ground.ground_range_m if command.ground is not None else None
            setpoint = velocity_setpoint(command.bearing, ground_range, self.config.guidance)
        else:
            setpoint = ZERO_VELOCITY  # lost, stopped, or no bearing estimate: hold position
        self.link.send(messages.velocity_target(self.link.mav, target, self.time_boot_ms(), setpoint))  # type: ignore[attr-defined]
        self.counters["velocity"] += 1

    def _follow(self, command: ControlCommand) -> None:
        if command.state not in (LoopState.TRACKING, LoopState.RECOVERED) or command.ground is None:
            return
        if not self._follow_warned and self.autopilot().autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
            # ArduCopter SITL: AP_Follow skips messages from its own system id, and the camera must share the
            # vehicle's (ground stations look for cameras there): FOLLOW never moves on our FOLLOW_TARGET
            log.warning("event=follow_target_ignored autopilot=ardupilot detail=\"ArduPilot's FOLLOW mode ignores "
                        "FOLLOW_TARGET from its own system id, which this camera uses; use guidance.mode velocity\"")
            self._follow_warned = True
        if not self._due(command, force=False):
            return
        self.link.send(messages.follow_target(self.link.mav, self.time_boot_ms(), command.ground))  # type: ignore[attr-defined]
        self.counters["follow_target"] += 1
