"""The demo's run summary for a reader: each figure with what it means, the daemon's counters likewise,
and its MAVLink command counts as accepted / refused-because (a ground station asking for camera
features this camera does not have is normal, and reads so); then the run's verdict against its bar.

Rows are (label, value, meaning); keys nobody explained yet are shown as they are, never dropped. A figure
with no frames to compute it on (None) reads "n/a (no such frames)".

The bar (BAR_*, one place): the closed loop passes when the car stayed in the image on BAR_IN_VIEW of the
run's frames, centred on BAR_CENTRED of the frames it could be seen on, the daemon never reported tracking
off the car for FALSE_LOCK_MIN_S or longer (a false lock), and the daemon was alive at the end.
`verdict(result)` is a pure function of the RunResult; `python -m sim.demo` exits 1 when it fails.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402  (after MAVLINK20)

if TYPE_CHECKING:
    from sim.closed_loop import RunResult

Row = tuple[str, Any, str]
NOT_AVAILABLE = "n/a (no such frames)"  # a figure over an empty set of frames (a median of nothing)

# ----- the bar ---------------------------------------------------------------------------------------
BAR_IN_VIEW = 0.95  # in_view_ratio: at least half of the car in the image, on this fraction of all run frames
BAR_CENTRED = 0.90  # centred_ratio: the car's centre in the central 20 %, on this fraction of the frames it is visible
# and: no false lock (sim.closed_loop.FALSE_LOCK_MIN_S of tracking reported off the car), the daemon alive at the end

# RunResult.summary() keys (sim.closed_loop): what each means.
RUN_MEANINGS = {
    "frames": "run frames the sim rendered and sent to the daemon (from the selection on; startup_frames apart)",
    "answered": "run frames the daemon answered with telemetry (the rest: skipped for a newer frame, see "
                "dropped_frames, or still in flight when the run ended)",
    "startup_frames": "frames sent before the run, while the daemon started, the ground station found the camera "
                      "and the car was selected (the daemon processed and counted them too)",
    "wall_s": "wall-clock seconds the run took",
    "sent_fps": "frames sent per wall-clock second",
    "processed_fps": "frames answered per wall-clock second",
    "dropped_frames": "frames the daemon skipped because a newer one had arrived (it keeps only the latest)",
    "skipped_frames": "real-time frames on the firmware not rendered because the sim was more than a frame late "
                      "(the firmware flies on regardless; 0 with the mock)",
    "gimbal_command_timeouts": "lockstep frames stepped without the daemon's gimbal command (should be 0)",
    "lost": "times the track was declared lost",
    "recovered": "times a lost track came back",
    "false_lock_frames": "frames reported tracking with the box off the car (further from it than its own size)",
    "false_lock_first_s": "when the track first left the car for >= 1 s while reporting tracking (simulated s; "
                          "n/a: it never did)",
    "centred_ratio": "fraction of frames, car visible, with the car's centre in the central 20 % of the image",
    "in_view_ratio": "fraction of all frames with at least half of the car in the image",
    "centring_error_px_median": "pixels from the image centre to the car's centre, median (car visible)",
    "centring_error_px_p90": "the same, 90th percentile",
    "lost_visible_frames": "frames reported lost while the car was visible",
    "lost_car_to_box_px_median": "on those frames: pixels from the car to the last box, median",
    "lost_visible_frames_first_3s": "lost-but-visible frames within 3 s of a loss (re-detection's window)",
    "lost_car_to_box_px_median_first_3s": "on those frames: pixels from the car to the last box, median",
    "latency_ms_p50": "daemon's time from reading a frame to sending its commands, median (ms)",
    "latency_ms_p99": "the same, 99th percentile (ms)",
    # the replay's own (sim.demo --replay)
    "track_rectangle": "the ground station's TRACK_RECTANGLE on the first ground-truth box: the camera's answer",
    "frames_sent": "frames of the recording sent to the daemon",
    "frames_processed": "frames of the recording the daemon answered with telemetry",
    "send_fps": "frames sent per wall-clock second",
    "centre_error_px_median": "pixels from the box's centre to the ground truth's centre, median",
    "autopilot_events": "the autopilot's last events (mock: mode changes, link drops; firmware: mode changes, its "
                        "messages)",
    "annotated_video": "the video with the car, the track and a colour legend drawn on it",
}

# The daemon's status counters (service.app.Service.status) other than the camera commands.
COUNTER_MEANINGS = {
    "frames": "frames the daemon processed: the startup frames plus the run frames it answered",
    "dropped_frames": "frames skipped for a newer one",
    "selections": "target selections applied",
    "lost": "track losses",
    "lost_drift": "of them: the box had left the target's colours while the tracker was confident (a slide caught)",
    "lost_appearance": "of them: the verifier called the tracked box another object while the tracker was confident",
    "recovered": "recoveries after a loss",
    "tracker_errors": "tracker failures (each stops the track)",
    "resized": "frame size changes followed",
    "clock_resets": "capture-clock jumps the controllers restarted on",
    "coasts": "losses the gimbal coasted through on the predicted target motion",
    "coasts_resumed": "losses soon after a re-acquisition (too short to fit a velocity, or whose fit contradicted the coast) that resumed the coast it had ended",
    "coast_frames": "frames spent coasting",
    "size_bounded_frames": "frames tracked with the range size bound set (box side held within a band around the "
                           "car's remembered ground size); how often it was set, not how often it changed the box",
    "frame_gap_holds": "holds while tracking because no frame came for 0.5 s after a step (zero rates / velocity, "
                       "the controllers reset); a lockstep run is only reproducible without them",
    "out_gimbal": "gimbal rate commands sent (287 ArduPilot, 282 PX4)",
    "out_claims": "PX4 gimbal-control claims sent (command 1001)",
    "out_velocity": "velocity setpoints sent (only in GUIDED / OFFBOARD)",
    "out_follow_target": "FOLLOW_TARGET messages sent",
    "out_gated": "commands with guidance held: autopilot silent or not in GUIDED / OFFBOARD",
    "out_px4_prestream": "zero setpoints streamed so the pilot can engage OFFBOARD (PX4)",
    "out_held": "commands held (none sent) while the autopilot's heartbeat was lost",
    "mavlink_sent": "MAVLink messages sent",
    "mavlink_send_errors": "sends the operating system refused",
    "mavlink_bad_packets": "packets received that were undecodable or failed signing",
    "mavlink_signing_refused_unsigned": "unsigned packets refused (signing on, mavlink.signing.allow_unsigned false)",
    "mavlink_signing_refused_bad_signature": "signed packets refused: wrong key, or a replayed or too old timestamp",
    "mavlink_status_sent": "tracking status messages (275) sent",
    "mavlink_texts_suppressed": "refusal texts (STATUSTEXT) not sent: more than 5 a second (the ACK still went)",
    "telemetry_errors": "telemetry samples that could not be published",
}

# The daemon's video outputs' counters, `<output>_<counter>` (service.video's LatestFrameWorker): each output's
# description, its name in a sentence, its rate setting and what it sends.
VIDEO_OUTPUTS = {
    "preview": {"what": "the preview (JPEG over Zenoh)", "name": "the preview", "rate": "video.preview.max_fps",
                "unit": "JPEG previews"},
    "stream": {"what": "the video stream (H.264 over RTP)", "name": "the stream", "rate": "video.stream.fps",
               "unit": "stream frames"},
}
VIDEO_COUNTER_MEANINGS = {
    "offered": "tracked frames handed to {what}",
    "rate_skipped": "of those, left out to hold {name} to {rate} (by design, not a loss)",
    "dropped": "replaced by a newer frame before {name}'s encoder took them (the encoder fell behind)",
    "sent": "{unit} encoded and sent",
    "errors": "{unit} that failed to encode or send",
    "cpu_ms": "CPU milliseconds {name}'s encoder used, on its own thread (not the tracking loop's)",
}

# How the daemon refused camera commands (counter suffix, label, meaning).
REFUSAL_KINDS = (
    ("unsupported", "not offered", "requests for what this camera does not have; ground stations poll for every "
                                   "camera feature, so this is expected"),
    ("denied", "bad parameters", "malformed or out-of-range command parameters"),
    ("temporarily", "not yet", "asked before the camera's first frame; the ground station retries"),
    ("failed", "failed", "valid but could not be carried out (the camera fails, or its file ended)"),
)
CAMERA_COMMAND_KEYS = {"mavlink_commands", "mavlink_accepted", "mavlink_rejected",
                       *(f"mavlink_rejected_{kind}" for kind, _, _ in REFUSAL_KINDS)}


def shown(value: Any) -> Any:
    """A figure as printed: None (nothing to compute it on) and NaN read NOT_AVAILABLE, never `None` / `nan`."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return NOT_AVAILABLE
    return value


def run_rows(summary: dict[str, Any]) -> list[Row]:
    """The run's figures in order, each with its meaning ('' for a key not explained here)."""
    return [(key, shown(value), RUN_MEANINGS.get(key, "")) for key, value in summary.items()]


def frame_accounting_row(summary: dict[str, Any], counters: dict[str, Any]) -> list[Row]:
    """Why the sim's and the daemon's frame counts differ: the daemon's `frames` = startup frames + answered run
    frames (`answered`; the replay's `frames_processed`); a difference left over is said, not hidden. [] without
    the daemon's count or the sim's."""
    answered = summary.get("answered", summary.get("frames_processed"))
    if "frames" not in counters or "startup_frames" not in summary or answered is None:
        return []
    startup, daemon = summary["startup_frames"], counters["frames"]
    expected = startup + answered
    if daemon == expected:
        meaning = "the daemon's frame count = startup_frames + answered run frames: they agree"
    else:
        meaning = (f"the daemon counted {daemon}, {abs(daemon - expected)} {'more' if daemon > expected else 'fewer'}"
                   " than startup_frames + answered (frames answered after the run stopped listening, or lost)")
    return [("frame accounting", f"{startup} + {answered} = {expected}", meaning)]


def command_name(command: int) -> str:
    """MAV_CMD name without its prefix, e.g. 512 -> REQUEST_MESSAGE; the number if unknown."""
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else f"command {command}"


def message_name(message_id: int) -> str:
    """Message name for an id, e.g. 260 -> CAMERA_SETTINGS; the number if unknown."""
    message = mavlink.mavlink_map.get(message_id)
    return message.msgname if message is not None else f"message {message_id}"


def camera_command_rows(counters: dict[str, Any], refusals: list[dict]) -> list[Row]:
    """Commands to the camera as accepted / refused, the refused split by why, and the kinds refused."""
    if "mavlink_commands" not in counters:
        return []
    accepted, refused = counters.get("mavlink_accepted", 0), counters.get("mavlink_rejected", 0)
    rows: list[Row] = [("camera commands", f"{accepted} accepted, {refused} refused",
                        "commands from ground stations to the camera component")]
    for kind, label, meaning in REFUSAL_KINDS:
        count = counters.get(f"mavlink_rejected_{kind}", 0)
        if count:
            rows.append((f"  refused: {label}", count, meaning))
    for refusal in refusals[:8]:  # the most frequent kinds: what was asked, how often, the answer's reason
        what = command_name(refusal["command"])
        if refusal.get("message") is not None:
            what += f" {message_name(refusal['message'])}"
        rows.append((f"    {what}", refusal["count"], f"{refusal['result']}: {refusal['reason']}"))
    return rows


def counter_meaning(key: str) -> str:
    """What a daemon counter counts ('' if nobody explained it yet)."""
    if key in COUNTER_MEANINGS:
        return COUNTER_MEANINGS[key]
    output, _, counter = key.partition("_")
    if output in VIDEO_OUTPUTS and counter in VIDEO_COUNTER_MEANINGS:
        return VIDEO_COUNTER_MEANINGS[counter].format(**VIDEO_OUTPUTS[output])
    return ""


def counter_rows(counters: dict[str, Any]) -> list[Row]:
    """The daemon's other counters with their meanings (unexplained ones as they are)."""
    return [(f"daemon {key}", shown(value), counter_meaning(key)) for key, value in counters.items()
            if key not in CAMERA_COMMAND_KEYS]


MAX_VALUE_WIDTH = 24


def format_rows(title: str, rows: list[Row]) -> str:
    """Aligned `label  value  meaning` lines under a title: the labels' column as wide as the longest label, the
    values' as the longest value of up to MAX_VALUE_WIDTH characters (a longer one, e.g. a file path, overflows
    rather than pushing every meaning right)."""
    label_width = max([36, *(len(label) for label, _, _ in rows)])
    value_width = max([12, *(len(str(value)) for _, value, _ in rows if len(str(value)) <= MAX_VALUE_WIDTH)])
    lines = [f"== {title} =="]
    for label, value, meaning in rows:
        lines.append(f"  {label:{label_width}s} {str(value):>{value_width}s}  {meaning}".rstrip())
    return "\n".join(lines)


# ----- the verdict -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """A run against the bar: passed, the figures judged (`checks`, as read) and why it failed (`reasons`)."""

    passed: bool
    checks: tuple[str, ...]
    reasons: tuple[str, ...]

    def line(self) -> str:
        """`VERDICT PASS: ...` with the figures against their bars, or `VERDICT FAIL: ...` with every reason."""
        if self.passed:
            return "VERDICT PASS: " + "; ".join(self.checks)
        return "VERDICT FAIL: " + "; ".join(self.reasons)


def percent(ratio: float) -> str:
    """0.643 -> '64 %' (rounded down: 94.6 % must not read as the 95 % bar)."""
    return f"{math.floor(100 * ratio + 1e-9):.0f} %"


def final_loss_s(result: "RunResult") -> float | None:
    """When the loss that lasted to the end of the run began (simulated s); None if the run ended on a track."""
    since = None
    for r in result.records:
        if r.state is None:
            continue
        if r.state == "lost":
            since = r.time_s if since is None else since
        else:
            since = None
    return since


def verdict(result: "RunResult") -> Verdict:
    """The closed-loop run against the bar (BAR_IN_VIEW, BAR_CENTRED, no false lock, daemon alive), from its
    records alone."""
    checks, reasons = [], []
    if not result.records or not any(r.state is not None for r in result.records):
        reasons.append("the daemon answered none of the run's frames")
    in_view = result.in_view_ratio()
    text = f"car in view on {percent(in_view)} of frames (bar {percent(BAR_IN_VIEW)})"
    (checks if in_view >= BAR_IN_VIEW else reasons).append(text)
    visible = sum(r.truth.visible for r in result.records)
    if visible:
        centred = result.centring_ratio()
        text = f"centred on {percent(centred)} of the {visible} frames it was visible (bar {percent(BAR_CENTRED)})"
        (checks if centred >= BAR_CENTRED else reasons).append(text)
    else:
        reasons.append("the car was never visible: nothing was centred")
    locks = result.false_locks()
    if locks:
        start, end = locks[0]
        off = sum(b - a for a, b in locks)
        reasons.append(f"the track left the car at {start:.1f} s while reporting tracking (off the car for "
                       f"{off:.1f} s in {len(locks)} stretch{'es' if len(locks) > 1 else ''})")
    else:
        checks.append("no false lock")
    if result.daemon_alive:
        checks.append("daemon alive")
    else:
        reasons.append(f"the daemon died (exit code {result.daemon_exit})")
    # why, on a failed run: a loss that lasted to the end while the car could be seen (on a passing run such a
    # loss is the car hidden at the end, not a failure)
    lost_since = final_loss_s(result)
    seen = sum(r.state == "lost" and r.truth.visible and r.time_s >= lost_since for r in result.records) \
        if lost_since is not None else 0
    if reasons and seen:
        reasons.append(f"the track was lost at {lost_since:.1f} s and never came back (the car visible on {seen} "
                       f"frames after that)")
    return Verdict(not reasons, tuple(checks), tuple(reasons))


def replay_verdict(result: "RunResult") -> Verdict:
    """A replay is open loop (its frames do not follow the gimbal): only the daemon is judged, alive at the end
    and answering frames; the box's error is in the summary, against no bar."""
    checks, reasons = ["open loop: centring not judged"], []
    if not any(r.state is not None for r in result.records):
        reasons.append("the daemon answered none of the recording's frames")
    if result.daemon_alive:
        checks.append("daemon alive")
    else:
        reasons.append(f"the daemon died (exit code {result.daemon_exit})")
    return Verdict(not reasons, tuple(checks), tuple(reasons))
