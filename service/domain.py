"""The tracking loop's own terms, shared with the adapters it drives (MAVLink, telemetry).

Selections come in, commands and snapshots go out in these types; adapters translate them from and
to wire formats (the MAVLink codes live in service.mavlink). The loop imports no adapter. Angles in
radians; boxes (x, y, w, h) pixels unless named normalised (fractions 0..1 of the image, origin
top-left, x right, y down).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from service.control.geo import GimbalAttitude, GroundTarget, VehiclePose


class LoopState(str, Enum):
    """The loop's track state after a frame; its value is the telemetry's "state" string."""

    IDLE = "idle"  # nothing selected
    TRACKING = "tracking"  # the tracker follows the target
    RECOVERED = "recovered"  # the tracker re-detected the target after a loss, on this frame
    LOST = "lost"  # the tracker lost the target: the gimbal coasts or holds

    def __str__(self) -> str:
        return self.value


class SelectionKind(str, Enum):
    """How the operator selected the current target."""

    POINT = "point"
    RECTANGLE = "rectangle"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class TrackPoint:
    """Track what is at (x, y) normalised; radius as a fraction of the image width (0 = default)."""

    x: float
    y: float
    radius: float


@dataclass(frozen=True)
class TrackRectangle:
    """Track the rectangle with normalised corners top-left (x0, y0), bottom-right (x1, y1)."""

    x0: float
    y0: float
    x1: float
    y1: float


@dataclass(frozen=True)
class StopTracking:
    """Stop tracking."""


class AutopilotState(Protocol):
    """What the loop reads of the autopilot (service.mavlink.autopilot.AutopilotView is one)."""

    @property
    def gimbal(self) -> GimbalAttitude | None:
        """Gimbal attitude as last reported, None = never heard."""

    def pose(self) -> VehiclePose | None:
        """Vehicle pose, None until both position and attitude were heard."""

    def fresh_heading_rate(self, now_s: float) -> float | None:
        """The vehicle's heading rate (rad/s, + = clockwise from above) if heard recently before now_s (time.monotonic()
        seconds), else None."""

    def alive(self, now_s: float, timeout_s: float) -> bool:
        """Heartbeat heard within timeout_s of now_s (time.monotonic() seconds)."""


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


@dataclass(frozen=True, kw_only=True)
class TrackSnapshot:
    """What the loop last reported, for the status messages: state, how the target was selected (None
    while idle), the target's normalised box (x, y, w, h) or None, the ground estimate or None, and the
    vehicle's altitude (m AMSL) or None."""

    state: LoopState = LoopState.IDLE
    selection: SelectionKind | None = None
    box_normalised: tuple[float, float, float, float] | None = None
    ground: GroundTarget | None = None
    vehicle_alt_amsl_m: float | None = None
