"""Range size bound (pure): the target's ground size, remembered from the track, bounds the box size.

The size filter models scale and aspect ratio, not in-plane rotation: a car that keeps turning shrinks the
box, and a re-initialisation on a half-hidden car grows it (docs/service.md, "Control"). A ground
target's pixel size follows from its range (geo.ground_px_per_m), which the service knows.
Sizes: `side` = sqrt(w * h) of the box, in pixels, or in metres on the ground (pixels / px_per_m). The
memory holds the box's ground side on confident frames, one sample every `every_s` s of capture time, at
most `max_samples`; their median (`reference_m`, computed when a sample is added) is the reference: the
track's own boxes, not the operator's looser rectangle, and a median moves slowly under a slow drift.
"""
from __future__ import annotations

import statistics
from dataclasses import dataclass


@dataclass(frozen=True)
class SizeMemory:
    """Ground-side samples (m) of the current track, their median (m; None before the first sample) and
    the capture time (s) of the last one."""

    samples: tuple[float, ...] = ()
    reference_m: float | None = None
    last_sample_s: float | None = None


def sample_due(memory: SizeMemory, time_s: float, every_s: float) -> bool:
    """Whether a sample at capture time `time_s` is taken: none yet, `every_s` passed, or the clock went back."""
    return memory.last_sample_s is None or not 0.0 <= time_s - memory.last_sample_s < every_s


def remember_side(memory: SizeMemory, time_s: float, side_m: float, every_s: float, max_samples: int) -> SizeMemory:
    """`memory` with `side_m` added if a sample is due (oldest dropped beyond max_samples)."""
    if not sample_due(memory, time_s, every_s):
        return memory
    samples = (memory.samples + (side_m,))[-max_samples:]
    return SizeMemory(samples, statistics.median(samples), time_s)


def side_bounds_px(reference_m: float, px_per_m: float, band: float) -> tuple[float, float]:
    """(lo, hi) px bounds on the box side: the reference side at px_per_m, divided / multiplied by band."""
    side_px = reference_m * px_per_m
    return side_px / band, side_px * band
