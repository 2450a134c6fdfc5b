"""Controller time step from the frames' capture timestamps (the source's clock, not the service's).

The gimbal controller integrates over the interval between the capture times of the frames it processes,
and guidance is throttled on the same clock: the result depends on the frames alone, so a lockstep
simulation or a replay is reproducible (v4l2 / file: read time; zenoh: the publisher's header timestamp).
An unusable interval resets the controller's memory instead of producing a spike: the first frame after a
(re)start, a capture time not later than the previous one, a gap over `reset_gap_s`, a frame id not above
the previous one, or a frame size change (the caller's). A usable one is clamped to [min_step_s, max_step_s].
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

IntervalReason = Literal["ok", "clamped", "first_frame", "time_not_increasing", "gap", "frame_id_not_increasing"]


@dataclass(frozen=True)
class FrameStamp:
    """A processed frame's source frame id and capture time (seconds, source clock)."""

    frame_id: int
    capture_time_s: float


@dataclass(frozen=True)
class ClockLimits:
    """Bounds on the controller time step, seconds of capture time."""

    min_step_s: float = 1e-3  # shorter (but increasing) intervals integrate as this
    max_step_s: float = 0.5  # longer intervals up to reset_gap_s integrate as this (dropped frames)
    reset_gap_s: float = 1.0  # a longer gap means a stalled / restarted stream: reset

    def __post_init__(self) -> None:
        if not 0 < self.min_step_s <= self.max_step_s <= self.reset_gap_s:
            raise ValueError(f"need 0 < min_step_s <= max_step_s <= reset_gap_s, got {self.min_step_s}, "
                             f"{self.max_step_s}, {self.reset_gap_s}")


@dataclass(frozen=True)
class ControlInterval:
    """dt_s: seconds to integrate over, or None = reset the controller memory; reason: why."""

    dt_s: float | None
    reason: IntervalReason

    @property
    def resets(self) -> bool:
        return self.dt_s is None


def control_interval(previous: FrameStamp | None, current: FrameStamp,
                     limits: ClockLimits = ClockLimits()) -> ControlInterval:
    """Controller step between two processed frames' capture stamps (previous None: first frame)."""
    if not math.isfinite(current.capture_time_s):
        raise ValueError(f"capture time must be finite, got {current.capture_time_s} (frame {current.frame_id})")
    if previous is None:
        return ControlInterval(None, "first_frame")
    if current.frame_id <= previous.frame_id:
        return ControlInterval(None, "frame_id_not_increasing")
    elapsed = current.capture_time_s - previous.capture_time_s
    if elapsed <= 0:
        return ControlInterval(None, "time_not_increasing")
    if elapsed > limits.reset_gap_s:
        return ControlInterval(None, "gap")
    clamped = min(max(elapsed, limits.min_step_s), limits.max_step_s)
    return ControlInterval(clamped, "ok" if clamped == elapsed else "clamped")
