"""JSAR-Re failure monitor: a pure, I/O-free state machine over the translation response peak.

Per frame: the raw translation peak (MATLAB FFT convention, jsar.config), the last confident box (x, y, w, h)
px, the image size and the 0-based frame index (0 = the initialisation frame).
- confident <=> peak > confident_peak (zeta_e) and peak > relative_drop x the reference, an asymmetric
  running mean of reliable committed peaks (fast up, slow down; the relative test is an addition);
- reliable <=> peak > reliable_peak (zeta_s, the paper's rule): the decision filter learns that sample;
- eligible <=> frame_index >= warmup_frames, min_area < w*h < max_area and the box inside the image
  (`inside_rule`). A frame that is not confident but not eligible is committed as plain JSAR.
Why the relative test and the asymmetric reference: docs/method.md ("JSAR-Re").
"""
from __future__ import annotations

from dataclasses import dataclass

from jsar.api import Box
from jsar.redetect.params import InsideRule, MonitorParams


@dataclass(frozen=True)
class Verdict:
    """One frame's judgement: commit (confident or not eligible), train the decision filter (reliable)."""

    confident: bool
    reliable: bool
    eligible: bool
    reference: float | None  # running mean of reliable peaks before this frame (None until the first)

    @property
    def lost(self) -> bool:
        """Not confident where a loss may be declared: do not commit, search."""
        return self.eligible and not self.confident


def box_is_inside(box: Box, image_wh: tuple[int, int], rule: InsideRule) -> bool:
    """Whether box (x, y, w, h) px lies inside a W x H image: whole box ("full") or its centre ("centre")."""
    x, y, w, h = box
    width, height = image_wh
    if rule == "full":
        return x >= 0 and y >= 0 and x + w <= width and y + h <= height
    cx, cy = x + w / 2, y + h / 2
    return 0 <= cx < width and 0 <= cy < height


def updated_reference(reference: float | None, value: float, rise_rate: float, fall_rate: float) -> float:
    """Asymmetric running mean (raw response units): fast towards a higher value, slow towards a lower."""
    if reference is None:
        return value
    return reference + (rise_rate if value > reference else fall_rate) * (value - reference)


class FailureMonitor:
    """Judges each frame's translation peak against the running reference of reliable peaks."""

    def __init__(self, params: MonitorParams = MonitorParams()) -> None:
        params.validate()
        self.params = params
        self.reference: float | None = None

    def eligible(self, box: Box, image_wh: tuple[int, int], frame_index: int) -> bool:
        """Whether a loss may be declared on this frame (warm-up over, target size and position sane)."""
        p = self.params
        area = box[2] * box[3]
        return (frame_index >= p.warmup_frames and p.min_area_px2 < area < p.max_area_px2
                and box_is_inside(box, image_wh, p.inside_rule))

    def judge(self, peak: float) -> tuple[bool, bool]:
        """(confident, reliable) for a raw peak against the current reference; changes nothing."""
        p = self.params
        reference = self.reference
        confident = peak > p.confident_peak and (reference is None or peak > p.relative_drop * reference)
        reliable = peak > p.reliable_peak
        return confident, reliable

    def assess(self, peak: float, box: Box, image_wh: tuple[int, int],
               frame_index: int) -> Verdict:
        """One frame's verdict from its raw translation peak and the last confident box (px). A
        reliable peak updates the reference when the frame will be committed (confident, or not
        eligible)."""
        if peak != peak or peak in (float("inf"), float("-inf")):
            raise ValueError(f"translation peak must be finite, got {peak}")
        confident, reliable = self.judge(peak)
        eligible = self.eligible(box, image_wh, frame_index)
        verdict = Verdict(confident, reliable, eligible, self.reference)
        if reliable and not verdict.lost:
            p = self.params
            self.reference = updated_reference(self.reference, peak, p.reference_rate, p.reference_fall_rate)
        return verdict

    def restart(self) -> None:
        """Forget the reference: the track was re-acquired and its peak level starts anew."""
        self.reference = None
