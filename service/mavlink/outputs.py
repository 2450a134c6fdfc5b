"""Loop decisions -> MAVLink messages: the gimbal backend (ardupilot / px4 / none) and guidance.

Guidance is gated on the autopilot's heartbeat (alive, GUIDED / OFFBOARD) and throttled to
guidance.rate_hz on the frames' capture clock (see `_due`); velocity mode commands zero velocity while the track is lost and once when it
stops. With PX4 outside OFFBOARD, zero-velocity setpoints stream while tracking, because PX4 only
lets the pilot engage OFFBOARD while a setpoint stream exists (and ignores it in other modes). follow_target sends FOLLOW_TARGET only while there is a ground estimate of a tracked target
(when it stops, the autopilot's follow timeout holds the vehicle). Never arms, never changes modes.
"""
from __future__ import annotations

import logging
from typing import Callable

from service.config import ServiceConfig
from service.control.guidance import MAV_AUTOPILOT_PX4, ZERO_VELOCITY, guidance_allowed, velocity_setpoint
from service.domain import ControlCommand, LoopState
from service.mavlink import messages
from service.mavlink.autopilot import MAV_COMP_ID_AUTOPILOT1, AutopilotView

log = logging.getLogger("service.control")


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
        self.counters = {"gimbal": 0, "claims": 0, "velocity": 0, "follow_target": 0, "gated": 0, "px4_prestream": 0}

    def apply(self, now_s: float, command: ControlCommand) -> None:
        """Send what `command` asks for; now_s: time.monotonic(), for heartbeat age and gimbal claims."""
        view = self.autopilot()
        system_id = view.system_id or self.config.mavlink.system_id
        if not system_id:
            return  # no autopilot heard and none configured: nobody to command yet
        target = (system_id, MAV_COMP_ID_AUTOPILOT1)
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

    # --- gimbal -------------------------------------------------------------------------------
    def _gimbal(self, now_s: float, view: AutopilotView, target: tuple[int, int], rates: tuple[float, float],
                tracking: bool) -> None:
        backend, gimbal = self.config.gimbal.backend, self.config.gimbal
        yaw_rate, pitch_rate = rates
        mav = self.link.mav  # type: ignore[attr-defined]
        if backend == "ardupilot":
            self.link.send(messages.gimbal_rates_ardupilot(mav, target, gimbal.device_id, yaw_rate, pitch_rate))  # type: ignore[attr-defined]
            self.counters["gimbal"] += 1
        elif backend == "px4":
            own = (self.link.system_id, self.config.mavlink.component_id)  # type: ignore[attr-defined]
            if view.gimbal_primary == own:
                self.link.send(messages.gimbal_rates_px4(mav, target, gimbal.device_id, yaw_rate, pitch_rate))  # type: ignore[attr-defined]
                self.counters["gimbal"] += 1
            # the claim is a handshake with the autopilot (it answers in real time): service clock
            elif tracking and (self._last_claim_s is None or now_s - self._last_claim_s >= gimbal.claim_interval_s):
                # PX4 honours 282 only from the primary controller: claim, then wait for 281 to confirm
                self.link.send(messages.gimbal_claim_px4(mav, target, own, gimbal.device_id))  # type: ignore[attr-defined]
                self._last_claim_s = now_s
                self.counters["claims"] += 1
                log.info("event=gimbal_claim primary=%s", view.gimbal_primary)

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
        if not self._due(command, force=False):
            return
        self.link.send(messages.follow_target(self.link.mav, self.time_boot_ms(), command.ground))  # type: ignore[attr-defined]
        self.counters["follow_target"] += 1
