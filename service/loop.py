"""The ONE tracking loop: frame -> tracker -> controller -> outputs (MAVLink, telemetry).

`TrackingLoop.step(frame)` is the whole per-frame work and does no I/O itself: selections arrive
through a one-slot mailbox, commands leave through an `Outputs` object, telemetry through a
callback. Angles in radians, boxes (x, y, w, h) pixels unless named normalised.

Two clocks, on purpose: the controllers run on the frames' capture clock (`Frame.capture_time_s`, see
service.control.frame_clock), so their output depends on the frames, not on how long a frame took to
process; detecting that frames stopped arriving (FRAME_GAP_S) and latencies use the service's
monotonic clock, because they are about the service's own real time.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Literal, Protocol

import numpy as np

from jsar.api import SideBoundedTracker, Tracker, TrackResult
from service.config import ServiceConfig
from service.control.coast import (CoastParams, CoastState, Position, TrackHistory, camera_angles, coast_step,
                                   plan_coast, remember, start_coast, velocity_change)
from service.control.frame_clock import ClockLimits, FrameStamp, control_interval
from service.control.geo import (GroundTarget, camera_ray_ned, gimbal_in_earth_frame, ground_px_per_m, locate_on_ground,
                                 relative_gimbal_yaw)
from service.control.gimbal import (GimbalState, PidGains, angular_error, focal_length_px, gimbal_step,
                                   vehicle_frame_yaw_rate)
from service.control.size_bound import SizeMemory, remember_side, sample_due, side_bounds_px
from service.domain import (AutopilotState, ControlCommand, LoopState, SelectionKind, StopTracking, TrackPoint,
                            TrackRectangle, TrackSnapshot)
from service.selection import (fitted_rectangle_box, normalised_box, point_box, proposal_box, rectangle_box,
                               rescale_box)
from service.sources.base import Frame, LatestSlot

log = logging.getLogger("service.loop")
CLOCK_LIMITS = ClockLimits()  # controller time step bounds, capture-clock seconds
FRAME_GAP_S = 0.5  # no frame for this long after a step, while tracking: hold gimbal and vehicle
SEARCH_LOG_EVERY_S = 1.0  # while lost, the re-detection's best candidate is logged at most this often (s)
REFUTING_CAUSES = ("drift", "appearance")  # loss causes that say the track before them followed something else


class Outputs(Protocol):
    """Where commands go (MAVLink in the service, a recorder in tests)."""

    def apply(self, now_s: float, command: ControlCommand) -> None:
        """now_s: the service's time.monotonic(); frame-clock decisions use command.frame_time_s."""


@dataclass(frozen=True)
class FrameReport:
    """Per-frame telemetry (published on <prefix>/track)."""

    frame_id: int
    capture_time_s: float
    image_size: tuple[int, int]
    box: tuple[float, float, float, float] | None
    box_normalised: tuple[float, float, float, float] | None
    score: float | None
    state: LoopState
    queue_ms: float
    track_ms: float
    total_ms: float  # frame read -> commands sent
    dropped_frames: int
    coasting: bool = False  # lost, and the gimbal turns at the target's last rate (not held)

    def as_json(self) -> dict[str, Any]:
        return {"frame_id": self.frame_id, "capture_time": self.capture_time_s,
                "image_size": list(self.image_size),
                "box_px": list(self.box) if self.box else None,
                "box_norm": list(self.box_normalised) if self.box_normalised else None,
                "score": self.score, "state": self.state, "coasting": self.coasting,
                "latency_ms": {"queue": round(self.queue_ms, 3), "track": round(self.track_ms, 3),
                               "total": round(self.total_ms, 3)},
                "dropped_frames": self.dropped_frames}


class TrackingLoop:
    """Owns the tracker and the gimbal controller state; one call to `step` per frame."""

    def __init__(self, config: ServiceConfig, selections: LatestSlot, make_tracker: Callable[[], Tracker],
                 outputs: Outputs, autopilot: Callable[[], AutopilotState],
                 publish_snapshot: Callable[[TrackSnapshot], None] = lambda snapshot: None,
                 publish_report: Callable[[FrameReport], None] = lambda report: None,
                 dropped: Callable[[], int] = lambda: 0,
                 publish_frame: Callable[[Frame], None] = lambda frame: None) -> None:
        self.config = config
        self.selections = selections
        self.make_tracker = make_tracker
        self.outputs = outputs
        self.autopilot = autopilot
        self.publish_snapshot = publish_snapshot
        self.publish_report = publish_report
        self.dropped = dropped
        self.publish_frame = publish_frame  # video outputs: must not block (service.video hands off)
        self.gains = PidGains.from_config(config.gimbal)
        self.coast_params = CoastParams.from_config(config.gimbal)
        self.hfov = math.radians(config.camera.hfov_deg)
        self.state = LoopState.IDLE
        self.selection_kind: SelectionKind | None = None  # how the current target was selected (point / rectangle)
        self.tracker: Tracker | None = None
        self.box: tuple[float, float, float, float] | None = None
        self.tracked_size: tuple[int, int] | None = None
        # first step after a reset: one nominal frame period (the configured source rate)
        self.nominal_dt_s = min(max(1.0 / config.source.fps, CLOCK_LIMITS.min_step_s), CLOCK_LIMITS.max_step_s)
        self.gimbal = GimbalState()
        self.last_stamp: FrameStamp | None = None  # the last frame the controller stepped on
        self.last_clock_reset: str | None = None  # reason of the last reset, to log each kind once
        self.halted = False  # zero commands already sent for the current frame gap
        self.history = TrackHistory()  # recent confident pointing, for the coast's rate estimate
        self.coast: CoastState | None = None  # the coast in progress while lost
        self.coast_decided = False  # this loss's coast was planned (or found impossible) already
        self.interrupted: CoastState | None = None  # the last coast, ended by a re-acquisition (_lost_command)
        self.reacquired_s = -math.inf  # capture time (s) of the frame whose re-acquisition ended that coast
        self.loss_cause: str | None = None  # why the current loss began, where the tracker says (_set_state)
        self.search_logged_s = -math.inf  # time.monotonic() of the last event=search line
        self.size_memory = SizeMemory()  # the track's ground sizes: the range size bound's reference
        self.view: AutopilotState | None = None  # the last frame's autopilot snapshot (the next size bound's)
        self.counters = {"frames": 0, "selections": 0, "lost": 0, "lost_drift": 0, "lost_appearance": 0, "recovered": 0, "tracker_errors": 0,
                         "resized": 0, "clock_resets": 0, "coasts": 0, "coasts_resumed": 0, "coast_frames": 0,
                         "size_bounded_frames": 0, "frame_gap_holds": 0}

    # --- the loop -----------------------------------------------------------------------------
    def run(self, mailbox: LatestSlot[Frame], should_stop: Callable[[], bool],
            on_iteration: Callable[[], None] = lambda: None) -> None:
        """Take the newest frame and step, until should_stop(); on_iteration pings the watchdog."""
        # The gap counts from the end of the last step, when its commands went out and the loop was ready
        # for the next frame: a step's own time is not a camera gap. Counted from the frame's arrival, a
        # step longer than FRAME_GAP_S / 2 (a slow CPU, re-detection) followed by one empty wait held a
        # camera that had not stopped, and the held controller's reset made the run depend on step times.
        ready_s = time.monotonic()
        while not should_stop():
            on_iteration()
            frame = mailbox.take(timeout_s=FRAME_GAP_S / 2)
            if frame is None:
                self._apply_selection_without_frame()
                if time.monotonic() - ready_s > FRAME_GAP_S:
                    self._hold_without_frames()
                continue
            self.halted = False
            try:
                self.step(frame)
            except Exception:  # noqa: BLE001 - never crash the daemon on one frame
                log.exception("event=step_failed frame_id=%d", frame.frame_id)
                self._stop_tracking("step failed")
            ready_s = time.monotonic()

    def step(self, frame: Frame) -> FrameReport:
        """Process one frame: apply a pending selection, track, take the autopilot snapshot, control, report."""
        start = time.monotonic()
        image = frame.image
        size = (image.shape[1], image.shape[0])
        self.counters["frames"] += 1
        change = self._apply_selection(image, size)
        stopped = change == "stopped"
        if self.tracker is not None and self.tracked_size != size:
            self._handle_resize(image, size)
        result: TrackResult | None = None
        if self.tracker is not None and change != "started":  # the init frame's box is the selection
            result = self._track(image)
        track_done = time.monotonic()
        # One snapshot of the autopilot a frame, taken once the tracker is done (the newest state the control
        # can have): this frame's size sample, control and status, and with this frame's box the next
        # update's size bound.
        view = self.view = self._mount_read(self.autopilot())
        confident = change == "started" or (result is not None and result.state == "tracking")
        if confident and self.box is not None:  # the selection, or a box the tracker is confident of
            self._remember_size(self.box, size, frame.capture_time_s, view)
            if change == "started" and self.size_memory.samples:
                log.info("event=target_size side_m=%.2f", self.size_memory.samples[0])
        command = self._control(frame, size, result, stopped, view)
        self.outputs.apply(time.monotonic(), command)
        sent = time.monotonic()
        box_norm = normalised_box(self.box, size) if self.box is not None and self.state != LoopState.IDLE else None
        pose = view.pose()
        self.publish_snapshot(TrackSnapshot(
            state=self.state, selection=self.selection_kind if self.state != LoopState.IDLE else None,
            box_normalised=box_norm, ground=command.ground, vehicle_alt_amsl_m=pose.alt_amsl_m if pose else None))
        report = FrameReport(
            frame_id=frame.frame_id, capture_time_s=frame.capture_time_s, image_size=size,
            box=self.box if self.state != LoopState.IDLE else None, box_normalised=box_norm,
            score=result.score if result is not None else None, state=self.state,
            queue_ms=(start - frame.read_monotonic_s) * 1e3, track_ms=(track_done - start) * 1e3,
            total_ms=(sent - frame.read_monotonic_s) * 1e3, dropped_frames=self.dropped(),
            coasting=command.coasting)
        self.publish_report(report)
        self.publish_frame(frame)  # after its telemetry: a preview frame's box is already on <prefix>/track
        return report

    # --- pieces -------------------------------------------------------------------------------
    def _apply_selection(self, image: np.ndarray, size: tuple[int, int]) -> Literal["started", "stopped"] | None:
        """Apply a pending selection: "started" (tracker initialised on this frame), "stopped", or None."""
        selection = self.selections.take(timeout_s=0.0)
        if selection is None:
            return None
        if isinstance(selection, StopTracking):
            return "stopped" if self._stop_tracking("stop requested") else None
        self.counters["selections"] += 1
        if isinstance(selection, TrackRectangle):
            box, kind, how = rectangle_box(selection, size), SelectionKind.RECTANGLE, "rectangle"
            if self.config.camera.rectangle_fit:
                fitted, outcome = fitted_rectangle_box(image, box, self.config.camera)
                how = "rectangle+fitted" if fitted is not None else f"rectangle,{outcome}"
                box = fitted or box
        elif isinstance(selection, TrackPoint):
            box, kind, how = point_box(selection, size, self.config.camera), SelectionKind.POINT, "point"
            if self.config.camera.point_proposal:
                proposal = proposal_box(image, selection, box, self.config.camera.min_box_px)
                how = "point+proposal" if proposal is not None else "point,no_proposal_qualified"
                box = proposal or box
        else:
            raise TypeError(f"unexpected selection {selection!r}")
        try:
            tracker = self.make_tracker()
            tracker.init(image, box)
        except ValueError as exc:
            log.error('event=track_init_failed box=%s reason="%s"', _fmt_box(box), exc)
            return "stopped" if self._stop_tracking("init failed") else None
        self.tracker, self.box, self.tracked_size, self.selection_kind = tracker, box, size, kind
        self.state = LoopState.TRACKING
        self._reset_controller()
        self._reset_coast()
        self.size_memory = SizeMemory()
        log.info("event=track_started how=%s box=%s size=%dx%d", how, _fmt_box(box), size[0], size[1])
        return "started"

    def _hold_without_frames(self) -> None:
        """No frame for FRAME_GAP_S after the last step while tracking: command zero rates / zero velocity once.

        Rate commands persist on some gimbals and velocity setpoints until the autopilot's timeout:
        without frames nothing would correct them, so the camera and vehicle are held still until
        frames come back (the track itself is kept and resumes with the next frame).
        """
        if self.tracker is None or self.halted:
            return
        self.halted = True
        self.counters["frame_gap_holds"] += 1
        self._reset_controller()
        if self.coast is not None:  # frames stopped: nothing measures the camera any more, hold
            log.info("event=coast_end reason=no_frames")
            self.coast = None
        log.warning("event=no_frames_while_tracking action=hold_gimbal_and_vehicle gap_s=%.1f", FRAME_GAP_S)
        self.outputs.apply(time.monotonic(), ControlCommand(state=LoopState.LOST, rates=(0.0, 0.0)))

    def _apply_selection_without_frame(self) -> None:
        """A stop must take effect even while no frames arrive (camera unplugged)."""
        pending = self.selections.take(timeout_s=0.0)
        if pending is None:
            return
        if isinstance(pending, StopTracking):
            if self._stop_tracking("stop requested"):
                self.outputs.apply(time.monotonic(), ControlCommand(state=LoopState.IDLE, stopped=True, rates=(0.0, 0.0)))
        else:
            self.selections.put(pending)  # keep it for the next frame

    def _stop_tracking(self, why: str) -> bool:
        was_active = self.tracker is not None
        if was_active:
            log.info("event=track_stopped reason=%s", why.replace(" ", "_"))
        self.tracker, self.box, self.tracked_size = None, None, None
        self.size_memory = SizeMemory()
        self.state, self.selection_kind = LoopState.IDLE, None
        self._reset_controller()
        self._reset_coast()
        return was_active

    def _handle_resize(self, image: np.ndarray, size: tuple[int, int]) -> None:
        """Frame size changed mid-stream: rescale the box (same field of view) and re-initialise."""
        assert self.box is not None and self.tracked_size is not None
        old = self.tracked_size
        box = rescale_box(self.box, old, size)
        self.counters["resized"] += 1
        log.warning("event=frame_size_changed old=%dx%d new=%dx%d box=%s", old[0], old[1], size[0], size[1], _fmt_box(box))
        try:
            tracker = self.make_tracker()
            tracker.init(image, box)
        except ValueError as exc:
            log.error('event=reinit_failed reason="%s"', exc)
            self._stop_tracking("re-init after resize failed")
            return
        self.tracker, self.box, self.tracked_size = tracker, box, size
        self._reset_controller()  # the angular error is continuous, but the box was re-initialised
        self._reset_coast()

    def _reset_controller(self) -> None:
        """Forget the gimbal controller's memory and the frame clock: the next step starts from rest."""
        self.gimbal = GimbalState()
        self.last_stamp = None

    def _reset_coast(self) -> None:
        """Forget the pointing history and any coast (new target, stop, re-initialisation)."""
        self.history = TrackHistory()
        self.coast = None
        self.coast_decided = False
        self.interrupted = None

    def _control_dt(self, frame: Frame) -> float:
        """Controller step (s) from the frame's capture time; resets the controller on an unusable interval."""
        stamp = FrameStamp(frame.frame_id, frame.capture_time_s)
        interval = control_interval(self.last_stamp, stamp, CLOCK_LIMITS)
        unexpected_reset = interval.resets and interval.reason != "first_frame"
        if unexpected_reset:
            self.counters["clock_resets"] += 1
            if interval.reason != self.last_clock_reset:  # once per kind in a row, not once per frame
                previous = self.last_stamp
                log.warning("event=control_clock_reset reason=%s frame_id=%d capture_time=%.6f "
                            "previous_frame_id=%s previous_capture_time=%s", interval.reason, frame.frame_id,
                            frame.capture_time_s, previous.frame_id if previous else None,
                            f"{previous.capture_time_s:.6f}" if previous else None)
            self.gimbal = GimbalState()
        self.last_clock_reset = interval.reason if unexpected_reset else None
        self.last_stamp = stamp
        return self.nominal_dt_s if interval.dt_s is None else interval.dt_s

    def _mount_read(self, view: AutopilotState) -> AutopilotState:
        """The autopilot's snapshot with the mount's attitude as the geometry reads it: a body-frame report
        (gimbal.attitude_frame: body) turned into the earth frame with the vehicle's attitude (without it, no
        mount attitude: a body-frame angle alone is off by the vehicle's tilt, 10-20 degrees while it brakes)."""
        if self.config.gimbal.attitude_frame == "earth" or view.gimbal is None:
            return view
        pose = view.pose()
        gimbal = None if pose is None else gimbal_in_earth_frame(view.gimbal, pose.roll, pose.pitch, pose.yaw)
        return dataclasses.replace(view, gimbal=gimbal)  # type: ignore[type-var]

    def _ground_px_per_m(self, box: tuple[float, float, float, float], size: tuple[int, int],
                         view: AutopilotState) -> float | None:
        """Pixels per metre of ground-target side where `box` (px) is, from the autopilot's pose and gimbal
        attitude (flat ground, see geo.ground_px_per_m); None without them or with the autopilot silent."""
        pose = view.pose()
        if (pose is None or view.gimbal is None
                or not view.alive(time.monotonic(), self.config.mavlink.heartbeat_timeout_s)):
            return None
        yaw_err, pitch_err = angular_error(box, size, self.hfov)
        ray = camera_ray_ned(yaw_err, pitch_err, view.gimbal, pose.yaw)
        return ground_px_per_m(pose, ray, yaw_err, pitch_err, focal_length_px(size[0], self.hfov))

    def _remember_size(self, box: tuple[float, float, float, float], size: tuple[int, int], time_s: float,
                       view: AutopilotState) -> None:
        """Add the ground side (m) of a box (px) the tracker is confident of to the size memory, if the
        geometry is known (one sample per range_size_sample_s of capture time)."""
        cfg = self.config.tracker
        if cfg.range_size_band == 0 or not sample_due(self.size_memory, time_s, cfg.range_size_sample_s):
            return  # the geometry is only worked out when a sample is due (once a second), not every frame
        px_per_m = self._ground_px_per_m(box, size, view)
        if px_per_m is not None:
            self.size_memory = remember_side(self.size_memory, time_s, math.sqrt(box[2] * box[3]) / px_per_m,
                                             cfg.range_size_sample_s, cfg.range_size_samples)

    def _bound_size(self, size: tuple[int, int]) -> None:
        """Bound the tracker's box side to [1/band, band] x the remembered ground size at the range of the
        last box, seen in the last frame's autopilot snapshot (service.control.size_bound); unbounded while
        the geometry or the memory is missing."""
        assert self.tracker is not None and self.box is not None
        band = self.config.tracker.range_size_band
        if band == 0:
            return
        if not isinstance(self.tracker, SideBoundedTracker):  # the service checks this at start
            raise TypeError(f"tracker {type(self.tracker).__name__} takes no side bounds (tracker.range_size_band)")
        reference_m = self.size_memory.reference_m
        px_per_m = (self._ground_px_per_m(self.box, size, self.view)
                    if reference_m is not None and self.view is not None else None)
        if px_per_m is None or reference_m is None:
            self.tracker.set_side_bounds(None)
            return
        self.tracker.set_side_bounds(side_bounds_px(reference_m, px_per_m, band))
        self.counters["size_bounded_frames"] += 1

    def _track(self, image: np.ndarray) -> TrackResult | None:
        assert self.tracker is not None
        size = (image.shape[1], image.shape[0])
        try:
            self._bound_size(size)
            result = self.tracker.update(image)
        except Exception as exc:  # noqa: BLE001 - a tracker failure is a lost track, not a crash
            self.counters["tracker_errors"] += 1
            log.error('event=tracker_error error="%s: %s"', type(exc).__name__, exc)
            self._set_state(LoopState.LOST)
            return None
        if all(math.isfinite(v) for v in result.box):
            self.box = result.box
        self._set_state(LoopState(result.state))
        if self.state == LoopState.LOST:
            self._log_search(time.monotonic())
        return result

    def _log_search(self, now_s: float) -> None:
        """While lost, at most once per SEARCH_LOG_EVERY_S: the re-detection's best candidate on this frame against
        its bar (trackers with a `last_step`, JSAR-Re's SearchStep), so that a loss that never ends can be read
        from the log: nothing near the target, or the target found and refused."""
        step = getattr(self.tracker, "last_step", None)
        if step is None or step.best is None or now_s - self.search_logged_s < SEARCH_LOG_EVERY_S:
            return
        self.search_logged_s = now_s
        best = step.best
        log.info("event=search best_score=%.3f bar=%.3f best_centre_px=%.0f,%.0f windows=%d taken=%s core_coasting=%s",
                 best.score, step.bar, best.x, best.y, step.windows, step.taken, step.coasting)

    def _set_state(self, state: LoopState) -> None:
        if state == self.state:
            return
        # Why a loss began, where the tracker says (JSAR-Re: "peak", "drift" for a box off the target's colours,
        # "appearance" for a box the verifier calls another object).
        cause = getattr(self.tracker, "loss_cause", None) if state == LoopState.LOST else None
        self.loss_cause = cause
        if state == LoopState.LOST:
            self.counters["lost"] += 1
            self.counters["lost_drift"] += cause == "drift"
            self.counters["lost_appearance"] += cause == "appearance"
        elif self.state == LoopState.LOST:
            self.counters["recovered"] += 1
        # How a loss ended, where the tracker says (JSAR-Re: its TRANSITIONS event, e.g. "core recovered").
        how = getattr(self.tracker, "last_event", None) if self.state == LoopState.LOST else None
        log.info("event=track_state from=%s to=%s%s%s", self.state, state, f" cause={cause}" if cause else "",
                 f' how="{how}"' if how else "")
        self.state = state

    def _control(self, frame: Frame, size: tuple[int, int], result: TrackResult | None, stopped: bool,
                 view: AutopilotState) -> ControlCommand:
        stamp = frame.capture_time_s
        if stopped or self.state == LoopState.IDLE:
            return ControlCommand(state=LoopState.IDLE, stopped=stopped, rates=(0.0, 0.0) if stopped else None,
                                  frame_time_s=stamp)
        if self.state == LoopState.LOST or self.box is None:
            return self._lost_command(stamp, view)
        if self.coast is not None:
            self.interrupted, self.reacquired_s = self.coast, stamp
        self.coast, self.coast_decided = None, False
        dt = self._control_dt(frame)
        if self.config.gimbal.backend != "none" and not view.alive(time.monotonic(),
                                                                   self.config.mavlink.heartbeat_timeout_s):
            # The gimbal is driven through the autopilot: with it silent no rate command arrives, the loop
            # is open, and an integrator fed the growing error would overshoot when the link comes back.
            self.gimbal = GimbalState()
        yaw_err, pitch_err = angular_error(self.box, size, self.hfov)
        self.gimbal, yaw_rate, pitch_rate = gimbal_step(self.gimbal, yaw_err, pitch_err, dt, self.gains)
        bearing: float | None = None
        ground: GroundTarget | None = None
        pose = view.pose()
        if view.gimbal is not None:
            gimbal_yaw = relative_gimbal_yaw(view.gimbal, pose.yaw if pose is not None else None)
            bearing = gimbal_yaw + yaw_err if gimbal_yaw is not None else None
            if pose is not None:
                ground = locate_on_ground(pose, camera_ray_ned(yaw_err, pitch_err, view.gimbal, pose.yaw))
        elif self.config.gimbal.backend == "none":
            bearing = yaw_err  # fixed camera, assumed looking along the vehicle's nose
        if ground is not None and pose is not None and view.gimbal is not None:
            camera = camera_angles(view.gimbal, pose.yaw)
            if camera is not None:
                self.history = remember(self.history, stamp, Position(pose.lat_deg, pose.lon_deg, pose.height_m),
                                        Position(ground.lat_deg, ground.lon_deg), camera, self.coast_params.fit_window_s)
        return ControlCommand(state=self.state, rates=self._relative_to_vehicle((yaw_rate, pitch_rate), view),
                              bearing=bearing, ground=ground, frame_time_s=stamp)

    def _relative_to_vehicle(self, rates: tuple[float, float], view: AutopilotState) -> tuple[float, float]:
        """The controllers' camera rates (yaw about the vertical, pitch; rad/s) as the gimbal's yaw rate relative to the
        vehicle's nose, the frame the commands are sent in, and the pitch rate unchanged (the gimbal holds pitch
        against the horizon)."""
        yaw = vehicle_frame_yaw_rate(rates[0], view.fresh_heading_rate(time.monotonic()), self.gains.max_rate)
        return yaw, rates[1]

    def _lost_command(self, stamp: float, view: AutopilotState) -> ControlCommand:
        """Lost: coast (service.control.coast) while the plan lasts, then hold the gimbal still.

        The tracking controller is reset (integrator, slew memory) on every lost frame; the coast starts
        from the tracking controller's last rates, so the gimbal does not jerk at the loss.
        """
        last_rates = (self.gimbal.yaw.last_output, self.gimbal.pitch.last_output)
        self._reset_controller()
        if not self.coast_decided:
            self.coast_decided = True
            plan = plan_coast(self.history, self.coast_params)
            interrupted, self.interrupted = self.interrupted, None
            resumable = interrupted is not None and stamp - interrupted.plan.start_s < self.coast_params.coast_s
            # A re-acquisition too short to fit a velocity on (a take refuted, a flicker) ends one loss episode, not
            # the coast: holding instead would let the target drive out of view. One shorter than the fit window
            # whose fit contradicts the coast it ended followed something else (the soak's canopy: a car at 5 m/s
            # fitted at 0.9 m/s from half a second on the canopy, and the camera stopped). A loss whose cause
            # refutes the track ("drift", "appearance": the tracker rolls it back) is tested so at any length: in
            # the hour's soak the watch ended a take on a canopy after 1.0 s, and a coast fitted on it drove the
            # camera away from the car.
            refuted = self.loss_cause in REFUTING_CAUSES
            contradicted = (resumable and plan is not None
                            and (refuted or stamp - self.reacquired_s < self.coast_params.fit_window_s)
                            and velocity_change(plan, interrupted.plan) > self.coast_params.resume_change_m_s)
            if resumable and (plan is None or contradicted):
                self.coast = interrupted
                self.counters["coasts_resumed"] += 1
                log.info("event=coast_resumed samples=%d elapsed_s=%.2f%s", len(self.history.samples),
                         stamp - interrupted.plan.start_s,
                         f" refused_velocity_ne_m_s={plan.velocity_ne[0]:.2f},{plan.velocity_ne[1]:.2f}" if plan else "")
            elif plan is not None:
                self.coast = start_coast(plan, last_rates)
                self.counters["coasts"] += 1
                log.info("event=coast_start target_velocity_ne_m_s=%.2f,%.2f samples=%d coast_s=%.1f",
                         plan.velocity_ne[0], plan.velocity_ne[1], len(self.history.samples), self.coast_params.coast_s)
            elif self.coast_params.coast_s > 0:
                log.info("event=coast_unavailable reason=short_history samples=%d (needs a ground estimate on "
                         ">= %d confident frames over %.2f s)", len(self.history.samples), self.coast_params.min_samples,
                         self.coast_params.min_span_s)
        if self.coast is not None:
            pose = view.pose()
            camera = camera_angles(view.gimbal, pose.yaw) if view.gimbal is not None and pose is not None else None
            vehicle = Position(pose.lat_deg, pose.lon_deg, pose.height_m) if pose is not None else None
            self.coast, rates = coast_step(self.coast, stamp, vehicle, camera, self.coast_params)
            if rates is not None:
                self.counters["coast_frames"] += 1
                return ControlCommand(state=LoopState.LOST, rates=self._relative_to_vehicle(rates, view),
                                      frame_time_s=stamp, coasting=True)
            log.info("event=coast_end reason=%s", "no_pose_or_gimbal_attitude" if camera is None else "coast_s_elapsed")
            self.coast = None
        return ControlCommand(state=LoopState.LOST, rates=(0.0, 0.0), frame_time_s=stamp)


def _fmt_box(box: tuple[float, float, float, float]) -> str:
    return "[" + ",".join(f"{v:.1f}" for v in box) + "]"
