"""The tracking loop's own terms, shared with the adapters it drives (MAVLink, telemetry).

The loop decides and reports in these types; adapters translate them to wire formats (the MAVLink
codes live in service.mavlink). The loop imports no adapter. Angles in radians; boxes (x, y, w, h)
pixels unless named normalised (fractions 0..1 of the image, origin top-left, x right, y down).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from service.control.geo import GroundTarget


class LoopState(str, Enum):
    """The loop's track state after a frame; its value is the telemetry's "state" string."""

    IDLE = "idle"  # nothing selected
    TRACKING = "tracking"  # the tracker follows the target
    RECOVERED = "recovered"  # the tracker re-detected the target after a loss, on this frame
    LOST = "lost"  # the tracker lost the target: the gimbal coasts or holds

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, kw_only=True)
class ControlCommand:
    """One decision for the outputs, built with keyword arguments.

    state: loop state after this frame; stopped: tracking just ended (send zeros once);
    rates: (yaw_rate, pitch_rate) rad/s, positive = yaw right / pitch up, or None (no gimbal command);
    bearing: target direction from the vehicle nose (rad, + right) or None; ground: flat-ground
    target estimate or None; frame_time_s: capture time (s, source clock) of the frame the command
    was computed from, the clock guidance is throttled on; None for commands not tied to a frame
    (hold after a frame gap, stop while no frames arrive). coasting: lost, and the rates are the
    coast's (service.control.coast), not a hold.
    """

    state: LoopState
    stopped: bool = False
    rates: tuple[float, float] | None = None
    bearing: float | None = None
    ground: GroundTarget | None = None
    frame_time_s: float | None = None
    coasting: bool = False
