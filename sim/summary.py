"""The demo's run summary for a reader: each figure with what it means, the daemon's counters likewise,
and its MAVLink command counts as accepted / refused-because (a ground station asking for camera
features this camera does not have is normal, and reads so).

Rows are (label, value, meaning); keys nobody explained yet are shown as they are, never dropped.
"""
from __future__ import annotations

import os
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402  (after MAVLINK20)

Row = tuple[str, Any, str]

# RunResult.summary() keys (sim.closed_loop): what each means.
RUN_MEANINGS = {
    "frames": "frames the sim rendered and sent to the daemon",
    "answered": "frames the daemon answered with telemetry",
    "wall_s": "wall-clock seconds the run took",
    "sent_fps": "frames sent per wall-clock second",
    "processed_fps": "frames answered per wall-clock second",
    "dropped_frames": "frames the daemon skipped because a newer one had arrived (it keeps only the latest)",
    "gimbal_command_timeouts": "lockstep frames stepped without the daemon's gimbal command (should be 0)",
    "lost": "times the track was declared lost",
    "recovered": "times a lost track came back",
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
    "frames_processed": "frames the daemon answered with telemetry",
    "send_fps": "frames sent per wall-clock second",
    "centre_error_px_median": "pixels from the box's centre to the ground truth's centre, median",
    "autopilot_events": "the mock autopilot's last events (mode changes, link drops)",
    "annotated_video": "the video with the car, the track and a colour legend drawn on it",
}

# The daemon's status counters (service.app.Service.status) other than the camera commands.
COUNTER_MEANINGS = {
    "frames": "frames the daemon processed",
    "dropped_frames": "frames skipped for a newer one",
    "selections": "target selections applied",
    "lost": "track losses",
    "recovered": "recoveries after a loss",
    "tracker_errors": "tracker failures (each stops the track)",
    "resized": "frame size changes followed",
    "clock_resets": "capture-clock jumps the controllers restarted on",
    "coasts": "losses the gimbal coasted through on the predicted target motion",
    "coast_frames": "frames spent coasting",
    "size_bounded_frames": "frames whose box the range size bound clamped",
    "out_gimbal": "gimbal rate commands sent (287 ArduPilot, 282 PX4)",
    "out_claims": "PX4 gimbal-control claims sent (command 1001)",
    "out_velocity": "velocity setpoints sent (only in GUIDED / OFFBOARD)",
    "out_follow_target": "FOLLOW_TARGET messages sent",
    "out_gated": "commands with guidance held: autopilot silent or not in GUIDED / OFFBOARD",
    "out_px4_prestream": "zero setpoints streamed so the pilot can engage OFFBOARD (PX4)",
    "mavlink_sent": "MAVLink messages sent",
    "mavlink_send_errors": "sends the operating system refused",
    "mavlink_bad_packets": "packets received that were undecodable or failed signing",
    "mavlink_status_sent": "tracking status messages (275) sent",
    "telemetry_errors": "telemetry samples that could not be published",
}

# How the daemon refused camera commands (counter suffix, label, meaning).
REFUSAL_KINDS = (
    ("unsupported", "not offered", "requests for what this camera does not have; ground stations poll for every "
                                   "camera feature, so this is expected"),
    ("denied", "bad parameters", "malformed or out-of-range command parameters"),
    ("temporarily", "not yet", "asked before the camera had frames; the ground station retries"),
    ("failed", "failed", "accepted but could not be carried out (e.g. no camera frames)"),
)
CAMERA_COMMAND_KEYS = {"mavlink_commands", "mavlink_accepted", "mavlink_rejected",
                       *(f"mavlink_rejected_{kind}" for kind, _, _ in REFUSAL_KINDS)}


def run_rows(summary: dict[str, Any]) -> list[Row]:
    """The run's figures in order, each with its meaning ('' for a key not explained here)."""
    return [(key, value, RUN_MEANINGS.get(key, "")) for key, value in summary.items()]


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


def counter_rows(counters: dict[str, Any]) -> list[Row]:
    """The daemon's other counters with their meanings (unexplained ones as they are)."""
    return [(f"daemon {key}", value, COUNTER_MEANINGS.get(key, "")) for key, value in counters.items()
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
