"""Closed loop: synthetic scene + mock autopilot + the real daemon (subprocess) over Zenoh and MAVLink.

Each frame: render the scene from the mock's vehicle + gimbal pose, publish it over Zenoh, (lockstep)
wait for the daemon's telemetry of that frame and for its gimbal command, then step the mock's
dynamics by one frame period of simulated time. The target is selected through the mavsdk ground
station (gcs.cli) on the ground-station link, routed by the mock autopilot to the daemon.

One simulated timeline stamps every frame (the daemon's controllers integrate over capture-time
intervals): startup and selection frames advance the sim clock by 1/fps each while the scene waits at
t = 0; the frame the selection is applied on (the init frame) is simulated time 0 of the run, and run
frame k is (k + 1)/fps after it. In lockstep the mock steps only once the daemon's gimbal command for
the frame has arrived (waited on by event), so a run depends on the frames, not on machine load;
after each step the mock pushes its heartbeat (flight mode) and state at once. Not synchronised: the
state travels over UDP and the next frame over Zenoh, so a daemon starved for longer than the sim
takes to render a frame could track that frame with the previous pose; `python -m sim.repro` checks.

The camera sees the synthetic scene (sim.scene), or any other World: `python -m sim.demo --replay`
runs the same loop on a recorded sequence (sim.replay.RecordingWorld), whose frames do not follow the
gimbal.

Centring (the tests' definition): the ground-truth centre of the car is within the central 20 % of
the image, |dx| <= 0.1 W and |dy| <= 0.1 H, measured on frames where >= 50 % of the car is visible.
"""
from __future__ import annotations

import logging
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import cv2
import numpy as np

import jsar
from jsar.api import SideBoundedTracker
from sim.autopilot import MockAutopilot
from sim.daemon import Daemon, deep_merge
from sim.ports import free_port  # also imported from here by sim.demo and the tests
from sim.scene import CameraConfig, CameraPose, GroundTruth, Scene, SceneConfig, pose_from_vehicle
from sim.vehicle_model import VehicleConfig
from sim.zenoh_link import SimCamera, ZenohEndpoints

log = logging.getLogger("sim.closed_loop")
Pace = Literal["lockstep", "realtime"]
GIMBAL_TYPES = ("GIMBAL_MANAGER_SET_PITCHYAW", "GIMBAL_MANAGER_SET_ATTITUDE")
SERVICE_COMPONENT = 100  # the daemon's MAVLink component id (config.yaml mavlink.component_id)
# What the daemon sends for every frame it tracks on: a gimbal rate command, or (PX4, before it is the
# primary gimbal controller) the MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE claim.
GIMBAL_OUTPUT_KEYS = tuple((SERVICE_COMPONENT, key) for key in (*GIMBAL_TYPES, "COMMAND_LONG:1001", "COMMAND_INT:1001"))
# The sim's capture clock starts at 2**20 s: every stamp of a run (< 2**20 s later) then lies in one
# binade, so a frame interval rounds the same whatever the number of startup / selection frames
# before the run, and two runs send the daemon bit-identical intervals.
SIM_CLOCK_EPOCH_S = float(2 ** 20)
# The run summary's "first 3 s of a loss": the window in which re-detection can find a car that drove
# under a canopy (the default scene's car reappears 1.2-1.8 s after the loss) and gimbal.coast_s's default.
LOST_EARLY_S = 3.0
# A false lock: the daemon reports tracking (or recovered) while its box's centre is off the car (further from
# the car's centre than the car's own width across or height down, or the car out of the image) for at least
# this long in a row. Shorter stretches are a box catching up with a turning car, not a lock on something else.
FALSE_LOCK_MIN_S = 1.0


class World(Protocol):
    """What the camera sees: the frame (BGR uint8, the config's camera size) and its ground truth at simulated
    time t (s after the init frame) from a camera pose (sim.scene.Scene is one)."""

    def render(self, pose: CameraPose, t: float) -> tuple[np.ndarray, GroundTruth]: ...


@dataclass(frozen=True)
class ClosedLoopConfig:
    """One run. Times are simulated seconds from the first frame."""

    flavour: str = "ardupilot"
    # "mock": sim.autopilot's model, stepped by the loop (lockstep possible); "firmware": ArduCopter SITL / PX4 SIH
    # (sim.sitl_autopilot) flying in real time, the scene rendered from what it reports
    autopilot: str = "mock"
    # firmware: its simulation's speed over real time during the run (ArduPilot SIM_SPEEDUP; PX4
    # PX4_SIM_SPEED_FACTOR, from boot); below 1 lets a loaded machine keep up, frames follow the firmware's clock
    speedup: float = 1.0
    duration_s: float = 20.0
    fps: float = 30.0
    pace: Pace = "lockstep"
    scene: SceneConfig = SceneConfig()
    camera: CameraConfig = CameraConfig()
    guidance: str = "off"  # daemon guidance.mode: off | velocity | follow_target
    tracker: str | None = None  # None: config.yaml's tracker
    link_drops: tuple[tuple[float, float], ...] = ()  # (start_s, duration_s) on the service link
    operator_modes: tuple[tuple[float, str], ...] = ()  # (time_s, mode): the pilot switches mode
    start_mode: str = ""  # "" = GUIDED / OFFBOARD
    altitude_m: float = 30.0  # vehicle height above the ground plane
    daemon_overrides: dict = field(default_factory=dict)
    daemon_module: str = "service"  # run as `python -m daemon_module` (tests: an instrumented service)
    telemetry_timeout_s: float = 15.0
    startup_timeout_s: float = 60.0
    video_path: Path | None = None  # annotated video (MJPG .avi)
    rss_every_s: float = 5.0  # sample the daemon's RSS and CPU time this often (simulated seconds)
    # Lockstep never runs faster than real time. The daemon's controllers run on the frames' capture
    # stamps (simulated time), but link health is judged on wall clocks: the daemon's autopilot
    # heartbeat timeout (mavlink.heartbeat_timeout_s, 1 Hz heartbeats) and its no-frames hold (0.5 s).
    # A sim faster than real time would compress a 5 s link drop below the heartbeat timeout.
    lockstep_realtime_floor: bool = True
    gimbal_command_timeout_s: float = 2.0  # lockstep: wait this long (wall) for a frame's gimbal command
    # Several drones at once: each its own autopilot system id and Zenoh key prefix; `zenoh_connect` adds
    # endpoints the daemon also connects to (e.g. a Zenoh router that ground stations reach).
    system_id: int = 1
    zenoh_prefix: str = "jsar"
    zenoh_connect: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.flavour not in ("ardupilot", "px4"):
            raise ValueError(f"flavour must be ardupilot or px4, got {self.flavour!r}")
        if not 0.05 <= self.speedup <= 10.0:
            raise ValueError(f"speedup must be in 0.05..10, got {self.speedup}")
        if self.autopilot not in ("mock", "firmware"):
            raise ValueError(f"autopilot must be mock or firmware, got {self.autopilot!r}")
        if self.autopilot == "firmware" and (self.pace != "realtime" or self.link_drops):
            raise ValueError("autopilot firmware runs on its own clock: pace must be realtime, and link_drops "
                             "(simulated by the mock) must be empty")
        if self.pace not in ("lockstep", "realtime"):
            raise ValueError(f"pace must be lockstep or realtime, got {self.pace!r}")
        if self.guidance not in ("off", "velocity", "follow_target"):
            raise ValueError(f"guidance must be off, velocity or follow_target, got {self.guidance!r}")
        if not (self.duration_s > 0 and self.fps > 0):
            raise ValueError("duration_s and fps must be > 0")
        if not self.gimbal_command_timeout_s > 0:
            raise ValueError(f"gimbal_command_timeout_s must be > 0, got {self.gimbal_command_timeout_s}")


@dataclass
class FrameRecord:
    """One frame of a run: simulated time, ground truth, the daemon's telemetry, vehicle state."""

    frame_id: int
    time_s: float
    truth: GroundTruth
    state: str | None  # daemon's state for this frame (None: no telemetry)
    box: tuple[float, float, float, float] | None
    latency_ms: float | None
    vehicle_ne: tuple[float, float]
    vehicle_speed: float
    mode: str
    link_down: bool

    @property
    def reports_track(self) -> bool:
        """The daemon reported this frame as tracking (or recovered): it claims its box is on the target."""
        return self.state in ("tracking", "recovered")

    def box_off_car(self) -> bool:
        """The reported box's centre is off the car: further from the car's centre than the car's width
        horizontally or its height vertically (the car's box grown by half its size on each side), or the car
        is not in the image at all. False without a box."""
        if self.box is None:
            return False
        if self.truth.in_view_fraction <= 0.0:
            return True
        x, y, w, h = self.box
        cx, cy = self.truth.centre
        _, _, car_w, car_h = self.truth.box
        return abs(x + w / 2 - cx) > car_w or abs(y + h / 2 - cy) > car_h

    def centred(self, width: int, height: int, fraction: float = 0.1) -> bool:
        """Ground-truth centre within +-fraction of the image size from the image centre."""
        cx, cy = self.truth.centre
        return abs(cx - width / 2) <= fraction * width and abs(cy - height / 2) <= fraction * height

    @property
    def target_distance_m(self) -> float:
        """Horizontal vehicle-to-car distance in metres (NaN where the car's position is unknown: a recording)."""
        if self.truth.target is None:
            return math.nan
        return math.hypot(self.truth.target.north - self.vehicle_ne[0], self.truth.target.east - self.vehicle_ne[1])


@dataclass(kw_only=True)
class RunResult:
    """Everything a run produced, for assertions and the demo summary."""

    records: list[FrameRecord]
    width: int
    height: int
    rss_kib: list[tuple[float, int]]  # (time_s, RSS)
    wall_s: float
    dropped_frames: int
    counters: dict[str, Any]
    daemon_alive: bool
    daemon_exit: int | None
    selection_result: str
    gimbal_command_timeouts: int = 0  # lockstep frames stepped without their gimbal command (see log)
    refusals: list = field(default_factory=list)  # the daemon's refused camera commands by kind (status query)
    cpu_s: list[tuple[float, float]] = field(default_factory=list)  # (time_s, daemon CPU seconds), with the RSS
    # frames sent before the run (daemon start-up, camera discovery, the selection): the daemon processed and
    # counted them too, so its `frames` counter is startup_frames + the run frames it answered
    startup_frames: int = 0
    skipped_frames: int = 0  # firmware, real time: frames not rendered because the loop ran more than a frame late

    def centring_ratio(self, exclude: tuple[tuple[float, float], ...] = ()) -> float:
        """Fraction of visible frames with the car in the central 20 %, outside the `exclude` windows."""
        frames = [r for r in self.records if r.truth.visible and not any(a <= r.time_s < b for a, b in exclude)]
        if not frames:
            return 0.0
        return sum(r.centred(self.width, self.height) for r in frames) / len(frames)

    def in_view_ratio(self) -> float:
        """Fraction of all frames with at least half of the car inside the image (occluded or not): what
        a track that wandered off the car, and the gimbal with it, loses."""
        if not self.records:
            return 0.0
        return sum(r.truth.in_view_fraction >= 0.5 for r in self.records) / len(self.records)

    def lost_recovered(self) -> tuple[int, int]:
        """Number of tracking->lost transitions and of lost->recovered/tracking transitions."""
        lost = recovered = 0
        previous = None
        for r in self.records:
            if r.state == "lost" and previous not in ("lost", None):
                lost += 1
            if previous == "lost" and r.state in ("recovered", "tracking"):
                recovered += 1
            previous = r.state if r.state is not None else previous
        return lost, recovered

    def false_locks(self, min_s: float = FALSE_LOCK_MIN_S) -> list[tuple[float, float]]:
        """Stretches (start_s, end_s) of at least min_s, simulated time, in which every answered frame was
        reported tracking with its box off the car (FrameRecord.box_off_car): the track had left the car
        while the daemon said it was on it. Unanswered frames neither break nor extend a stretch."""
        spans: list[tuple[float, float]] = []
        start = end = None
        for r in self.records:
            if r.state is None:
                continue
            if r.reports_track and r.box_off_car():
                start = r.time_s if start is None else start
                end = r.time_s
                continue
            if start is not None and end - start >= min_s:
                spans.append((start, end))
            start = end = None
        if start is not None and end - start >= min_s:
            spans.append((start, end))
        return spans

    def box_error_px(self) -> list[float]:
        """On frames with the car visible and a reported box: pixels from the car's centre to the box's centre."""
        return [math.hypot(r.truth.centre[0] - (r.box[0] + r.box[2] / 2), r.truth.centre[1] - (r.box[1] + r.box[3] / 2))
                for r in self.records if r.box is not None and r.truth.visible]

    def lost_car_to_box_px(self, within_s: float = math.inf) -> list[float]:
        """On lost frames with the car visible, at most within_s simulated seconds after the loss began:
        pixels from the car's centre to the reported box's centre (the last confident box, around which
        re-detection searches; what coasting keeps small)."""
        gaps, lost_since, previous = [], None, None
        for r in self.records:
            if r.state is not None:
                if r.state == "lost" and previous != "lost":
                    lost_since = r.time_s
                previous = r.state
            if r.state == "lost" and r.box is not None and r.truth.visible and lost_since is not None \
                    and r.time_s - lost_since <= within_s:
                x, y, w, h = r.box
                gaps.append(math.hypot(r.truth.centre[0] - (x + w / 2), r.truth.centre[1] - (y + h / 2)))
        return gaps

    def summary(self) -> dict[str, Any]:
        """Frames, fps, drops, lost / recovered counts, centring error (pixels, visible frames), distance
        of the car from the box while lost."""
        errors = [math.hypot(r.truth.centre[0] - self.width / 2, r.truth.centre[1] - self.height / 2)
                  for r in self.records if r.truth.visible]
        lost_gaps, early_gaps = self.lost_car_to_box_px(), self.lost_car_to_box_px(within_s=LOST_EARLY_S)
        latencies = [r.latency_ms for r in self.records if r.latency_ms is not None]
        lost, recovered = self.lost_recovered()
        false_locks = self.false_locks()
        return {"frames": len(self.records), "answered": sum(r.state is not None for r in self.records),
                "startup_frames": self.startup_frames,
                "wall_s": round(self.wall_s, 2),
                "sent_fps": round(len(self.records) / max(self.wall_s, 1e-9), 1),
                "processed_fps": round(sum(r.state is not None for r in self.records) / max(self.wall_s, 1e-9), 1),
                "dropped_frames": self.dropped_frames, "skipped_frames": self.skipped_frames,
                "gimbal_command_timeouts": self.gimbal_command_timeouts,
                "lost": lost, "recovered": recovered,
                "false_lock_frames": sum(r.reports_track and r.box_off_car() for r in self.records),
                "false_lock_first_s": round(false_locks[0][0], 2) if false_locks else None,
                "centred_ratio": round(self.centring_ratio(), 3),
                "in_view_ratio": round(self.in_view_ratio(), 3),
                "centring_error_px_median": round(float(np.median(errors)), 1) if errors else None,
                "centring_error_px_p90": round(float(np.percentile(errors, 90)), 1) if errors else None,
                "lost_visible_frames": len(lost_gaps),
                "lost_car_to_box_px_median": round(float(np.median(lost_gaps)), 1) if lost_gaps else None,
                "lost_visible_frames_first_3s": len(early_gaps),
                "lost_car_to_box_px_median_first_3s": round(float(np.median(early_gaps)), 1) if early_gaps else None,
                "latency_ms_p50": round(float(np.percentile(latencies, 50)), 1) if latencies else None,
                "latency_ms_p99": round(float(np.percentile(latencies, 99)), 1) if latencies else None}


def daemon_overrides(cfg: ClosedLoopConfig, zenoh_port: int) -> dict[str, Any]:
    """config.yaml overrides that point the daemon at this sim."""
    overrides: dict[str, Any] = {
        "source": {"kind": "zenoh"},
        "camera": {"hfov_deg": cfg.camera.hfov_deg},
        # ArduPilot's servo mount reports its angles against the vehicle's body (docs/sim.md, mock versus firmware);
        # the mock's ArduPilot flavour does the same
        "gimbal": {"backend": cfg.flavour, "attitude_frame": "body" if cfg.flavour == "ardupilot" else "earth"},
        "guidance": {"mode": cfg.guidance},
        "zenoh": {"enabled": True, "mode": "peer", "listen": [],
                  "connect": [f"tcp/127.0.0.1:{zenoh_port}", *cfg.zenoh_connect],
                  "multicast_scouting": False, "prefix": cfg.zenoh_prefix},
    }
    if cfg.tracker is not None:
        overrides["tracker"] = {"name": cfg.tracker, "params": {}}
        if not isinstance(jsar.create(cfg.tracker), SideBoundedTracker):
            overrides["tracker"]["range_size_band"] = 0  # e.g. csrt: the daemon refuses the bound for it
    return deep_merge(overrides, cfg.daemon_overrides)


# Colours (BGR) of the annotated videos, and what each one marks.
TRUTH_COLOUR, BOX_COLOUR, LOST_COLOUR, CENTRE_COLOUR = (0, 255, 0), (0, 255, 255), (0, 0, 255), (255, 255, 255)
LEGEND = ((TRUTH_COLOUR, "car (ground truth)"), (BOX_COLOUR, "daemon's box"),
          (LOST_COLOUR, "daemon's box, lost (last known)"), (CENTRE_COLOUR, "central 20 % (centring goal)"))
TEXT_FONT, TEXT_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.45


def draw_status_line(image: np.ndarray, text: str) -> None:
    """White text on a dark bar along the bottom of the image, in place; the font shrinks to fit the width.
    One rendering of the text: an outline drawn thicker advances wider and smears the line."""
    h, w = image.shape[:2]
    (text_w, text_h), baseline = cv2.getTextSize(text, TEXT_FONT, TEXT_SCALE, 1)
    scale = TEXT_SCALE * min(1.0, (w - 16) / max(text_w, 1))
    (text_w, text_h), baseline = cv2.getTextSize(text, TEXT_FONT, scale, 1)
    top = h - text_h - baseline - 8
    cv2.rectangle(image, (0, top), (w - 1, h - 1), (0, 0, 0), -1)
    cv2.putText(image, text, (8, h - baseline - 4), TEXT_FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)


def draw_legend(image: np.ndarray, entries: tuple[tuple[tuple[int, int, int], str], ...] = LEGEND) -> None:
    """A key in the top-left corner, in place: a colour swatch and what it marks, one entry a line."""
    line_h, swatch = 16, 10
    width = 16 + swatch + max(cv2.getTextSize(label, TEXT_FONT, 0.4, 1)[0][0] for _, label in entries)
    cv2.rectangle(image, (0, 0), (width, 6 + line_h * len(entries)), (0, 0, 0), -1)
    for i, (colour, label) in enumerate(entries):
        y = 6 + i * line_h
        cv2.rectangle(image, (6, y + 2), (6 + swatch, y + 2 + swatch), colour, -1)
        cv2.putText(image, label, (12 + swatch, y + 11), TEXT_FONT, 0.4, (255, 255, 255), 1, cv2.LINE_AA)


def annotate(frame: np.ndarray, record: FrameRecord) -> np.ndarray:
    """Copy of the frame with the ground truth, the daemon's box (normal / lost), the central 20 % window,
    a legend of those colours and a status line (time, state, flight mode, link, distance to the car)."""
    out = frame.copy()
    h, w = out.shape[:2]
    cv2.rectangle(out, (int(0.4 * w), int(0.4 * h)), (int(0.6 * w), int(0.6 * h)), CENTRE_COLOUR, 1)
    if record.truth.visible:
        x, y, bw, bh = record.truth.box
        cv2.rectangle(out, (int(x), int(y)), (int(x + bw), int(y + bh)), TRUTH_COLOUR, 1)
    if record.box is not None:
        x, y, bw, bh = record.box
        colour = LOST_COLOUR if record.state == "lost" else BOX_COLOUR
        cv2.rectangle(out, (int(x), int(y)), (int(x + bw), int(y + bh)), colour, 2)
    draw_legend(out)
    draw_status_line(out, f"t={record.time_s:.1f} s  {record.state or 'not answered (daemon took a newer frame)'}  mode {record.mode}"
                          f"{'  LINK DOWN' if record.link_down else ''}{_distance_text(record)}")
    return out


def _centring_text(record: FrameRecord, width: int, height: int) -> str:
    """The status line's centring error: pixels from the image centre to the car's, or why there is none
    (the car hidden under cover or out of the image), in the same width."""
    if record.truth.visible:
        cx, cy = record.truth.centre
        return f"{math.hypot(cx - width / 2, cy - height / 2):6.1f} px"
    return "out of view" if record.truth.in_view_fraction < 0.5 else "car hidden "


def _distance_text(record: FrameRecord) -> str:
    """The status text's vehicle-to-car distance; empty where the car's position is unknown (a recording)."""
    distance = record.target_distance_m
    return f"  dist {distance:5.1f} m" if math.isfinite(distance) else ""


@dataclass
class RunProgress:
    """A run under way: what ClosedLoop.run collects frame by frame. Times in seconds."""

    dt: float  # frame period, simulated
    writer: "cv2.VideoWriter | None"  # the annotated video, if asked for
    start_wall: float  # time.monotonic() at the first run frame
    firmware_start: float  # the firmware's clock then (0 with the mock)
    drops: list[tuple[float, float]]  # link drops still to come: (start_s, duration_s)
    modes: list[tuple[float, str]]  # the pilot's mode switches still to come: (time_s, mode)
    records: list[FrameRecord] = field(default_factory=list)
    pending: list[tuple[int, FrameRecord, np.ndarray | None]] = field(default_factory=list)  # real time: matched later
    rss: list[tuple[float, int]] = field(default_factory=list)  # (time_s, daemon RSS KiB)
    cpu: list[tuple[float, float]] = field(default_factory=list)  # (time_s, daemon CPU s)
    next_rss: float = 0.0  # simulated time of the next RSS / CPU sample
    skipped: int = 0  # firmware: frames dropped because the loop ran more than a frame late


class ClosedLoop:
    """Owns the mock autopilot, the Zenoh camera, the daemon and the scene for one run."""

    def __init__(self, cfg: ClosedLoopConfig, workdir: Path | None = None, world: World | None = None) -> None:
        """world: what the camera sees; None = the synthetic scene of cfg.scene and cfg.camera."""
        self.cfg = cfg
        self._tmp = tempfile.TemporaryDirectory(prefix="jsar-sim-") if workdir is None else None
        self.workdir = Path(self._tmp.name) if self._tmp is not None else workdir
        self.service_port, self.gcs_port = free_port(2), free_port(2)  # SOCK_DGRAM
        self.zenoh_port = free_port(1)  # SOCK_STREAM
        self.scene = Scene(cfg.scene, cfg.camera) if world is None else world
        if cfg.autopilot == "firmware":
            from sim.sitl_autopilot import SitlAutopilot
            # opens nothing yet (an instance number's lock file and a temporary folder, freed by close)
            self.autopilot: Any = SitlAutopilot(cfg.flavour, self.gcs_port, cfg.altitude_m,
                                                reengage_offboard=cfg.guidance != "off", speedup=cfg.speedup)
            try:
                self.daemon = Daemon(self.workdir, daemon_overrides(cfg, self.zenoh_port), self.autopilot.service_url,
                                     cfg.daemon_module)
            except BaseException:
                self.autopilot.close()
                raise
        else:
            # The daemon's config first (it opens nothing): a failure here leaves no socket or session behind.
            self.daemon = Daemon(self.workdir, daemon_overrides(cfg, self.zenoh_port),
                                 f"udpout:127.0.0.1:{self.service_port}", cfg.daemon_module)
            # PX4's gimbal set up as on the firmware's closed loop (sim.sitl_autopilot: MNT_RANGE_PITCH 180)
            self.autopilot = MockAutopilot(VehicleConfig(flavour=cfg.flavour, start_mode=cfg.start_mode,
                                                         start_altitude_m=cfg.altitude_m, system_id=cfg.system_id,
                                                         px4_pitch_range_deg=180.0),
                                           self.service_port, self.gcs_port)
        try:
            self.camera = SimCamera(ZenohEndpoints(listen=(f"tcp/127.0.0.1:{self.zenoh_port}",),
                                                   prefix=cfg.zenoh_prefix))
        except BaseException:
            # Nothing else would close the autopilot's sockets: the caller never got the object.
            self.autopilot.close()
            raise
        self.gcs = None
        self.frame_id = 0
        self.clock_s = SIM_CLOCK_EPOCH_S  # capture stamp of the next startup / selection frame
        self.init_stamp_s: float | None = None  # capture stamp of the frame the selection was applied on
        self.gimbal_command_timeouts = 0
        self.status_line = ""

    # ----- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "ClosedLoop":
        """Start the mock and the daemon; wait for the daemon's heartbeat and its first telemetry. A daemon
        that exits meanwhile (e.g. a configuration error) ends the wait at once: DaemonExited with its log."""
        self.autopilot.start()
        self.daemon.start()
        # the daemon's exit wakes whoever waits on it: the heartbeat, telemetry, gimbal-command waits
        self.daemon.on_exit(self.autopilot.wake_waiters)
        self.daemon.on_exit(self.camera.telemetry.mark_source_gone)
        heard = self.autopilot.wait_for_heartbeat(SERVICE_COMPONENT, self.cfg.startup_timeout_s,
                                                  unless=self.daemon.exited.is_set)
        if self.daemon.exited.is_set():
            raise self.daemon.exited_error("at start, before its first heartbeat")
        if not heard:
            raise RuntimeError(f"no heartbeat from the daemon (component {SERVICE_COMPONENT}) within "
                               f"{self.cfg.startup_timeout_s} s; log:\n{self.daemon.log_tail()}")
        deadline = time.monotonic() + self.cfg.startup_timeout_s
        frame, _ = self.render(0.0)
        while self.camera.telemetry.last is None:  # the daemon's subscriber may not be declared yet
            if self.daemon.exited.is_set():
                raise self.daemon.exited_error("at start, before its first telemetry")
            if time.monotonic() > deadline:
                raise RuntimeError(f"no telemetry from the daemon; log:\n{self.daemon.log_tail()}")
            self.publish(frame)  # re-sent every 0.5 s until the subscriber is there; the wait ends on exit too
            self.camera.telemetry.wait_frame(self.frame_id, 0.5)
        return self

    def close(self) -> int | None:
        """Stop everything; returns the daemon's exit code."""
        if self.gcs is not None:
            self.gcs.close()
            self.gcs = None
        code = self.daemon.stop()
        self.camera.close()
        self.autopilot.close()
        if self._tmp is not None:
            self._tmp.cleanup()
        return code

    def __enter__(self) -> "ClosedLoop":
        try:
            return self.start()
        except BaseException:
            self.close()
            raise

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- pieces -------------------------------------------------------------------------------
    def camera_pose(self) -> CameraPose:
        """The camera's pose from the autopilot side's vehicle and gimbal state now (mock or firmware)."""
        s = self.autopilot.snapshot()
        return pose_from_vehicle(s.north, s.east, s.down, s.yaw, s.gimbal_pitch, s.gimbal_yaw)

    def render(self, t: float) -> tuple[np.ndarray, GroundTruth]:
        return self.scene.render(self.camera_pose(), t)

    def publish(self, frame: np.ndarray, run_time_s: float | None = None) -> int:
        """Send a frame stamped on the sim clock: run_time_s (simulated s after the init frame) for run
        frames; otherwise (startup, selection, after the run) the next 1/fps tick of the sim clock."""
        self.frame_id += 1
        if run_time_s is None:
            stamp = self.clock_s
        else:
            if self.init_stamp_s is None:
                raise ValueError("run frames need the init frame's stamp: select the target first")
            stamp = self.init_stamp_s + run_time_s
        self.clock_s = stamp + 1.0 / self.cfg.fps
        self.camera.publish(frame, self.frame_id, stamp)
        return self.frame_id

    def gimbal_outputs(self) -> int:
        """How many gimbal commands (or PX4 gimbal claims) the daemon's component has sent the mock (0 with
        firmware, which does not say: it is never lockstep)."""
        if not self.autopilot.lockstep:
            return 0
        counts = self.autopilot.stats.received_by_source
        return sum(counts[key] for key in GIMBAL_OUTPUT_KEYS)

    def wait_gimbal_output(self, before: int, frame_id: int) -> bool:
        """Lockstep: wait (event, cfg.gimbal_command_timeout_s) for the daemon's gimbal output of frame_id,
        i.e. a count above `before` (taken just before the frame was published). A timeout is counted
        and logged: the mock then steps without that command and the run is no longer reproducible."""
        counts = self.autopilot.stats.received_by_source
        arrived = self.autopilot.wait_for(lambda: sum(counts[key] for key in GIMBAL_OUTPUT_KEYS) > before,
                                          self.cfg.gimbal_command_timeout_s)
        if not arrived:
            self.gimbal_command_timeouts += 1
            log.warning("event=gimbal_command_timeout frame_id=%d timeout_s=%.1f count=%d", frame_id,
                        self.cfg.gimbal_command_timeout_s, self.gimbal_command_timeouts)
        return arrived

    def wait_telemetry(self, frame_id: int, timeout_s: float) -> dict[str, Any]:
        """The daemon's telemetry of exactly frame_id; RuntimeError (with the daemon's log) on timeout,
        DaemonExited at once if the daemon has exited."""
        sample = self.camera.telemetry.wait_frame(frame_id, timeout_s)
        if sample is None and self.daemon.exited.is_set():
            raise self.daemon.exited_error(f"waiting for frame {frame_id}'s telemetry")
        if sample is None or int(sample["frame_id"]) != frame_id:
            raise RuntimeError(f"no telemetry for frame {frame_id} within {timeout_s} s (got "
                               f"{None if sample is None else sample['frame_id']}); log:\n{self.daemon.log_tail()}")
        return sample

    def select_target(self, timeout_s: float = 30.0) -> str:
        """Select the car through the mavsdk ground station (TRACK_RECTANGLE on its ground-truth box),
        re-sending the t = 0 frame until the daemon reports tracking. Returns the command result."""
        from gcs.cli import GroundStation
        self.gcs = GroundStation(f"udpout://127.0.0.1:{self.gcs_port}", discovery_timeout_s=timeout_s)
        frame, truth = self.render(0.0)
        # Keep frames flowing while mavsdk discovers the camera (CAMERA_INFORMATION needs a frame size).
        info = None
        deadline = time.monotonic() + timeout_s
        while info is None:
            self.publish(frame)
            self.camera.telemetry.wait_frame(self.frame_id, 0.5)
            try:
                info = self.gcs.wait_for_camera(0.2)
            except TimeoutError:
                if self.daemon.exited.is_set():
                    raise self.daemon.exited_error("while the ground station looked for its camera") from None
                if time.monotonic() > deadline:
                    raise
        self.gcs.set_status_interval(info.component_id, 0.1)
        # No frame in flight when the selection arrives: the init frame is then one the loop below
        # published and waited for (its stamp and gimbal output are known exactly).
        self.wait_telemetry(self.frame_id, self.cfg.telemetry_timeout_s)
        x, y, w, h = truth.box
        W, H = self.cfg.camera.width, self.cfg.camera.height
        result = self.gcs.track_rectangle(info.component_id, x / W, y / H, (x + w) / W, (y + h) / H)
        while True:
            gimbal_before = self.gimbal_outputs()
            frame_id = self.publish(frame)
            sample = self.wait_telemetry(frame_id, self.cfg.telemetry_timeout_s)
            if sample.get("state") == "tracking":
                self.init_stamp_s = float(sample["capture_time"])
                if self.cfg.pace == "lockstep":
                    self.wait_gimbal_output(gimbal_before, frame_id)
                return result.name
            if time.monotonic() > deadline:
                raise TimeoutError(f"daemon did not start tracking; log:\n{self.daemon.log_tail()}")

    # ----- the run ------------------------------------------------------------------------------
    def run(self, live: bool = False) -> RunResult:
        """Run cfg.duration_s of simulated time after the selection; returns the per-frame record."""
        cfg = self.cfg
        selection = self.select_target()
        startup_frames = self.frame_id  # every frame so far came before the run (ids count from 1)
        frames = int(round(cfg.duration_s * cfg.fps))
        progress = self._begin_run()
        step = self._lockstep_frame if cfg.pace == "lockstep" else self._realtime_frame
        for k in range(frames):
            t = (k + 1) * progress.dt  # simulated time after the init frame
            self._operator_events(progress, t)
            self._sample_usage(progress, t)
            if not self._firmware_ready(progress, t):
                progress.skipped += 1
                continue
            step(progress, k, t)
            if live and (k % 10 == 0 or k == frames - 1):
                shown = [pending[1] for pending in progress.pending[-1:]] or progress.records
                self._print_status(k, frames, progress.start_wall, shown)
            if not self.daemon.alive():
                break
        return self._end_run(progress, selection, startup_frames, live)

    def _begin_run(self) -> RunProgress:
        """Open the video, let the init frame's command act for one frame period (as every run frame's
        does) and start the clocks."""
        cfg = self.cfg
        writer = None
        if cfg.video_path is not None:
            cfg.video_path.parent.mkdir(parents=True, exist_ok=True)
            writer = cv2.VideoWriter(str(cfg.video_path), cv2.VideoWriter_fourcc(*"MJPG"), cfg.fps,
                                     (cfg.camera.width, cfg.camera.height))
        dt = 1.0 / cfg.fps
        self.autopilot.step(dt)
        if cfg.pace == "lockstep":
            self.autopilot.send_state_now()
        return RunProgress(dt=dt, writer=writer, start_wall=time.monotonic(),
                           firmware_start=self.autopilot.firmware_time_s() if not self.autopilot.lockstep else 0.0,
                           drops=sorted(cfg.link_drops), modes=sorted(cfg.operator_modes))

    def _operator_events(self, progress: RunProgress, t: float) -> None:
        """The link drops and the pilot's mode switches due by simulated time t."""
        while progress.drops and progress.drops[0][0] <= t:
            self.autopilot.drop_link(progress.drops.pop(0)[1])
        while progress.modes and progress.modes[0][0] <= t:
            mode = progress.modes.pop(0)[1]
            try:
                self.autopilot.request_mode(mode)
            except ValueError as exc:
                with self.autopilot.lock:
                    self.autopilot.events.append((t, f"operator switch to {mode} refused: {exc}"))

    def _sample_usage(self, progress: RunProgress, t: float) -> None:
        """The daemon's RSS and CPU time every cfg.rss_every_s of simulated time."""
        if t >= progress.next_rss and self.daemon.alive():
            progress.rss.append((t, self.daemon.rss_kib()))
            progress.cpu.append((t, self.daemon.cpu_s()))
            progress.next_rss += self.cfg.rss_every_s

    def _firmware_ready(self, progress: RunProgress, t: float) -> bool:
        """Firmware: frames keep to the firmware's own clock (real time, or cfg.speedup times it): wait for
        time t on it; False for a frame the loop is more than a frame late for, dropped as a real camera's
        would be. The mock: True at once."""
        if self.autopilot.lockstep:
            return True
        if self.autopilot.firmware_time_s() - progress.firmware_start > t + progress.dt:
            return False
        self.autopilot.wait_firmware_time(progress.firmware_start + t, 5.0 * progress.dt / self.cfg.speedup + 1.0)
        return True

    def _shoot(self, t: float) -> tuple[np.ndarray, FrameRecord, int]:
        """Render and publish run frame at simulated time t from the vehicle's pose now: the frame, its record
        (no telemetry yet) and the gimbal output count just before it was published."""
        snap = self.autopilot.snapshot()
        frame, truth = self.scene.render(pose_from_vehicle(snap.north, snap.east, snap.down, snap.yaw,
                                                           snap.gimbal_pitch, snap.gimbal_yaw), t)
        gimbal_before = self.gimbal_outputs()
        frame_id = self.publish(frame, t)
        record = FrameRecord(frame_id=frame_id, time_s=t, truth=truth, state=None, box=None, latency_ms=None,
                             vehicle_ne=(snap.north, snap.east), vehicle_speed=math.hypot(snap.v_north, snap.v_east),
                             mode=snap.mode, link_down=self.autopilot.link_is_down("service"))
        return frame, record, gimbal_before

    def _lockstep_frame(self, progress: RunProgress, k: int, t: float) -> None:
        """One lockstep frame: publish, wait for its telemetry and gimbal command, then step the mock."""
        frame, record, gimbal_before = self._shoot(t)
        sample = self.camera.telemetry.wait_frame(record.frame_id, self.cfg.telemetry_timeout_s)
        if sample is not None and int(sample["frame_id"]) == record.frame_id:
            self._fill(record, sample)
            if sample.get("state") != "idle" and not record.link_down:
                self.wait_gimbal_output(gimbal_before, record.frame_id)
        if progress.writer is not None:
            progress.writer.write(annotate(frame, record))
        progress.records.append(record)
        self.autopilot.step(progress.dt)
        self.autopilot.send_state_now()
        if self.cfg.lockstep_realtime_floor:
            delay = progress.start_wall + (k + 1) * progress.dt - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing (see lockstep_realtime_floor), not synchronisation

    def _realtime_frame(self, progress: RunProgress, k: int, t: float) -> None:
        """One real-time frame: publish, take in the telemetry that has come, keep the frame rate (the mock;
        firmware keeps its own clock), step the mock."""
        frame, record, _ = self._shoot(t)
        progress.pending.append((record.frame_id, record, frame if progress.writer is not None else None))
        self._collect(progress.pending, progress.records, progress.writer, final=False)
        due = progress.start_wall + (k + 1) * progress.dt
        delay = due - time.monotonic() if self.autopilot.lockstep else 0.0
        if delay > 0:
            self.camera.telemetry.wait_frame(record.frame_id, delay)  # pacing; returns early on telemetry
            remaining = due - time.monotonic()
            if remaining > 0:
                time.sleep(remaining)  # pacing a real-time camera, not synchronisation
        self.autopilot.step(progress.dt)

    def _end_run(self, progress: RunProgress, selection: str, startup_frames: int, live: bool) -> RunResult:
        """Take in the last telemetry (real time), close the video, ask the daemon for its counters."""
        wall = time.monotonic() - progress.start_wall
        if self.cfg.pace == "realtime":
            self.camera.telemetry.wait_frame(self.frame_id, 2.0)
            self._collect(progress.pending, progress.records, progress.writer, final=True)
        if progress.writer is not None:
            progress.writer.release()
        if live:
            print(flush=True)
        status = (self.camera.status(2.0) if self.daemon.alive() else None) or {}
        last = self.camera.telemetry.last or {}
        alive = self.daemon.alive()
        return RunResult(records=progress.records, width=self.cfg.camera.width, height=self.cfg.camera.height,
                         rss_kib=progress.rss, wall_s=wall, dropped_frames=int(last.get("dropped_frames", 0) or 0),
                         counters=status.get("counters", {}), daemon_alive=alive,
                         daemon_exit=None if alive else self.daemon.process.returncode,
                         selection_result=selection, gimbal_command_timeouts=self.gimbal_command_timeouts,
                         refusals=status.get("mavlink_refusals", []), cpu_s=progress.cpu,
                         startup_frames=startup_frames, skipped_frames=progress.skipped)

    def _collect(self, pending: list, records: list[FrameRecord], writer: "cv2.VideoWriter | None",
                 final: bool) -> None:
        """Real time: move frames the daemon has answered (or skipped: a later frame was answered) from
        `pending` to `records`, oldest first, so the telemetry log's bounded window never misses them."""
        last = self.camera.telemetry.last
        newest = int(last["frame_id"]) if last else 0
        done = 0
        for frame_id, record, frame in pending:
            if frame_id > newest and not final:
                break
            sample = self.camera.telemetry.by_frame.get(frame_id)
            if sample is not None:
                self._fill(record, sample)
            if writer is not None and frame is not None:
                writer.write(annotate(frame, record))
            records.append(record)
            done += 1
        del pending[:done]

    @staticmethod
    def _fill(record: FrameRecord, sample: dict[str, Any]) -> None:
        record.state = sample.get("state")
        box = sample.get("box_px")
        record.box = tuple(box) if box else None
        latency = (sample.get("latency_ms") or {}).get("total")
        record.latency_ms = float(latency) if latency is not None else None

    def _print_status(self, k: int, frames: int, start_wall: float, records: list[FrameRecord]) -> None:
        r = records[-1]
        state = r.state or (self.camera.telemetry.last or {}).get("state") or "-"
        elapsed = time.monotonic() - start_wall
        print(f"\rframe {k + 1:5d}/{frames}  sim {r.time_s:6.1f} s  {(k + 1) / max(elapsed, 1e-9):5.1f} fps  "
              f"state {state:9s}  centring error {_centring_text(r, self.cfg.camera.width, self.cfg.camera.height)}  "
              f"mode {r.mode:8s}{_distance_text(r)} ", end="", flush=True)
