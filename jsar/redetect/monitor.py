"""JSAR-Re failure monitor: a pure, I/O-free state machine over the translation response peak.

Per frame the caller passes the raw translation peak (the tracker's FFT convention: forward DFT
unnormalised, inverse 1/N, as MATLAB, so the peak is the spatial correlation value and a filter's
response to its own training sample peaks near the Gaussian label's 1), the last confident target box
(x, y, w, h) in pixels, the image size and the 0-based frame index (0 = the initialisation frame).

Rules (paper, Algorithm 1, and the original's gating, with the choices stated here):
- confident  <=> peak > enable_peak (zeta_e) and peak > relative_drop * reference, where reference
  is an asymmetric running mean of the peaks of reliable frames (rate reference_rate towards a
  higher peak, reference_fall_rate towards a lower one). The relative test is an addition to the
  paper: our features give per-target peak levels from about 0.013 (a deforming bird) to 0.06, so a
  target replaced by background can halve the peak and still stay above the absolute zeta_e.
  relative_drop = 0 gives the paper's rule. Commit the frame as usual when confident;
- reliable   <=> peak > reliable_peak (zeta_s) and peak > reliable_fraction * reference: train the
  decision filter on that sample and update the reference. The band (an addition) matters for
  GRADUAL occlusions (the synthetic scene's canopy: 0.057 -> 0.019 over ~20 frames): had every frame
  above zeta_s updated the reference, it would follow the decline down and the relative test would
  never fire, and the decision filter would learn the occluder. Below the band the reference is
  frozen; a slow appearance change (within the band) is still followed at reference_fall_rate;
- re-detect  <=> not confident and eligible, where eligible = frame_index >= warmup_frames (the
  original's "after frame 30", 1-based) and min_area < w*h < max_area and the box is inside the image
  (`inside_rule`: "full" = the whole box, as the original; "centre" = its centre, which keeps
  re-detection available while the target leaves the view across a border). A frame that is not
  confident but not eligible is committed as usual (plain JSAR behaviour).
- the first accept_holdoff frames of a loss hand out eta_d = inf (no acceptance: the caller skips
  the proposal search), an addition, see assess();
- while re-detecting, each failed attempt multiplies omega by omega_growth (up to omega_max, an
  addition: the paper lets it grow without bound) and divides eta_d by accept_decay for the next
  frame; an accepted proposal or a confident frame resets omega and eta_d to their initial values.
  The eta_d handed out is at least accept_fraction * reference (decaying with eta_d), an addition:
  with a target whose peak level is 0.057, background under the canopy scored 0.023 > eta_d 0.02
  and was accepted; a proposal must score like the target did. It is also at most
  accept_ceiling_fraction * reference: the absolute eta_d can lie above a weak target's own level. The monitor never asks for a re-initialisation other than on the frame a
  proposal is accepted (the original's never-cleared flag retrained from scratch on every later frame).
- distrust(): the tracker's verification (verifier.py) gave the track up; no frame is confident until
  the next re-initialisation (reinitialised()), however high the peak.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

InsideRule = Literal["full", "centre"]


@dataclass(frozen=True)
class MonitorParams:
    """Failure-monitor thresholds; peaks in the tracker's raw response units (MATLAB FFT scaling)."""

    enable_peak: float = 0.01  # zeta_e (paper 0.0105; the original's code 0.01)
    reliable_peak: float = 0.013  # zeta_s
    accept_peak: float = 0.02  # eta_d at the first failed frame
    omega: float = 5.0  # side of the proposal square, in units of sqrt(w*h)
    omega_growth: float = 1.05
    omega_max: float = math.inf
    accept_decay: float = 1.005
    warmup_frames: int = 30
    min_area_px2: float = 100.0
    max_area_px2: float = 20000.0
    inside_rule: InsideRule = "full"
    relative_drop: float = 0.6  # 0 disables the relative test (paper's absolute rule only)
    reference_rate: float = 0.1  # update rate of the reference peak towards a HIGHER peak
    reference_fall_rate: float = 0.02  # ... towards a LOWER peak (slow: a gradual occlusion must not drag it down)
    reliable_fraction: float = 0.7  # reliable also needs peak > this * reference (0: zeta_s alone); 0.8 lost the deforming Gull2 bird at frame 41
    accept_fraction: float = 0.5  # eta_d is at least this * reference (decaying with eta_d); 0: absolute only
    accept_holdoff: int = 5  # no acceptance on the first this-many frames of a loss (eta_d = inf); 0: none
    accept_ceiling_fraction: float = 0.0  # eta_d is at most this * reference (0: no ceiling); see assess()

    def __post_init__(self) -> None:
        if not 0 < self.enable_peak <= self.reliable_peak:
            raise ValueError(
                f"need 0 < enable_peak <= reliable_peak, got {self.enable_peak}, {self.reliable_peak}")
        if self.accept_peak <= 0 or self.omega <= 0:
            raise ValueError(f"accept_peak and omega must be > 0, got {self.accept_peak}, {self.omega}")
        if self.omega_max < self.omega:
            raise ValueError(f"omega_max must be >= omega, got {self.omega_max} < {self.omega}")
        if self.omega_growth < 1 or self.accept_decay < 1:
            raise ValueError(
                f"omega_growth and accept_decay must be >= 1, got {self.omega_growth}, {self.accept_decay}")
        if self.warmup_frames < 0 or not 0 <= self.min_area_px2 < self.max_area_px2:
            raise ValueError("need warmup_frames >= 0 and 0 <= min_area_px2 < max_area_px2")
        if not 0 <= self.relative_drop < 1 or not 0 < self.reference_rate <= 1:
            raise ValueError(
                f"need 0 <= relative_drop < 1 and 0 < reference_rate <= 1, got {self.relative_drop}, "
                f"{self.reference_rate}")
        if self.accept_holdoff < 0:
            raise ValueError(f"need accept_holdoff >= 0, got {self.accept_holdoff}")
        if not 0 <= self.accept_fraction < 1:
            raise ValueError(f"need 0 <= accept_fraction < 1, got {self.accept_fraction}")
        if self.accept_ceiling_fraction and not self.accept_fraction < self.accept_ceiling_fraction <= 1:
            raise ValueError(f"need accept_ceiling_fraction 0 or in (accept_fraction, 1], got "
                             f"{self.accept_ceiling_fraction}")
        if not 0 < self.reference_fall_rate <= 1 or not 0 <= self.reliable_fraction < 1:
            raise ValueError(
                f"need 0 < reference_fall_rate <= 1 and 0 <= reliable_fraction < 1, got "
                f"{self.reference_fall_rate}, {self.reliable_fraction}")
        if self.inside_rule not in ("full", "centre"):
            raise ValueError(f"inside_rule must be 'full' or 'centre', got {self.inside_rule!r}")


@dataclass(frozen=True)
class Verdict:
    """What to do with one frame: redetect (do not commit; search proposals with omega, accept above eta_d)."""

    redetect: bool
    reliable: bool
    omega: float
    eta_d: float
    failed_frames: int  # consecutive frames with a failed re-detection before this one
    reference: float | None  # running mean of reliable peaks (None until the first reliable frame)


def box_is_inside(box: tuple[float, float, float, float], image_wh: tuple[int, int], rule: InsideRule) -> bool:
    """Whether box (x, y, w, h) px lies inside a W x H image: whole box ("full") or its centre ("centre")."""
    x, y, w, h = box
    width, height = image_wh
    if rule == "full":
        return x >= 0 and y >= 0 and x + w <= width and y + h <= height
    cx, cy = x + w / 2, y + h / 2
    return 0 <= cx < width and 0 <= cy < height


def updated_reference(reference: float | None, peak: float, rise_rate: float, fall_rate: float) -> float:
    """Asymmetric running mean of peaks (raw response units): fast towards higher, slow towards lower."""
    if reference is None:
        return peak
    return reference + (rise_rate if peak > reference else fall_rate) * (peak - reference)


class FailureMonitor:
    """Decides per frame between committing, re-detecting, and training the decision filter."""

    def __init__(self, params: MonitorParams = MonitorParams()) -> None:
        self.params = params
        self._omega = params.omega
        self._eta_d = params.accept_peak
        self._failed_frames = 0
        self._awaiting_result = False
        self._reference: float | None = None
        self._distrusted = False

    @property
    def searching(self) -> bool:
        """True after a failed re-detection until a proposal is accepted or a frame is confident."""
        return self._failed_frames > 0

    def eligible(self, box: tuple[float, float, float, float], image_wh: tuple[int, int], frame_index: int) -> bool:
        """Whether re-detection may run on this frame (warm-up over, target size and position sane)."""
        p = self.params
        area = box[2] * box[3]
        return (frame_index >= p.warmup_frames and p.min_area_px2 < area < p.max_area_px2
                and box_is_inside(box, image_wh, p.inside_rule))

    def assess(self, peak: float, box: tuple[float, float, float, float], image_wh: tuple[int, int],
               frame_index: int) -> Verdict:
        """One frame's verdict from its raw translation peak and the last confident box (pixels)."""
        if not math.isfinite(peak):
            raise ValueError(f"translation peak must be finite, got {peak}")
        if self._awaiting_result:
            raise RuntimeError("assess() called again before redetection_result() of the last re-detection")
        p = self.params
        reference = self._reference
        confident = (not self._distrusted and peak > p.enable_peak
                     and (reference is None or peak > p.relative_drop * reference))
        if confident or not self.eligible(box, image_wh, frame_index):
            if confident:
                self._reset()
            reliable = peak > p.reliable_peak and (reference is None or peak > p.reliable_fraction * reference)
            if reliable:
                # Frozen below reliable_fraction * reference: a gradual occlusion leaves that band
                # within a few frames and cannot drag the reference down with it.
                self._reference = updated_reference(reference, peak, p.reference_rate, p.reference_fall_rate)
            return Verdict(False, reliable, self._omega, self._eta_d, self._failed_frames, reference)
        self._awaiting_result = True
        eta_d = self._eta_d
        if reference is not None:
            # Relative floor: a proposal must score like the target did, not merely above the absolute
            # eta_d (background under a filter with a high peak level can exceed eta_d); it decays
            # with eta_d, so a long absence still lowers the bar.
            eta_d = max(eta_d, p.accept_fraction * reference * self._eta_d / p.accept_peak)
            if p.accept_ceiling_fraction > 0:
                # Ceiling: the paper's absolute eta_d (0.02) can lie above a weak target's own level
                # (the Gull2 bird tracked at 0.018 and reappeared at 0.014-0.015 with eta_d at 0.016).
                eta_d = min(eta_d, p.accept_ceiling_fraction * reference)
        if self._failed_frames < p.accept_holdoff:
            # The first frames of a loss are a target sliding under cover: a proposal there is the
            # half-hidden target next to its occluder, and re-initialising on it teaches the new
            # filter the occluder (closed-loop scene: accepted at 50 % visibility, then followed the
            # canopy). The search still runs from the first frame after the hold-off.
            eta_d = math.inf
        return Verdict(True, False, self._omega, eta_d, self._failed_frames, reference)

    def redetection_result(self, accepted: bool) -> None:
        """Report the outcome of the re-detection `assess` asked for: accepted resets, failure widens."""
        if not self._awaiting_result:
            raise RuntimeError("redetection_result() without a re-detection verdict from assess()")
        self._awaiting_result = False
        if accepted:
            self.reinitialised()
        else:
            self._failed_frames += 1
            self._omega = min(self._omega * self.params.omega_growth, self.params.omega_max)
            self._eta_d /= self.params.accept_decay

    @property
    def distrusted(self) -> bool:
        """The track failed verification and no re-initialisation has happened since."""
        return self._distrusted

    def distrust(self) -> None:
        """The track failed verification (verifier.py): no frame counts as confident until a
        re-initialisation, however high the translation peak (the filter follows the wrong thing)."""
        self._distrusted = True

    def reinitialised(self) -> None:
        """The tracker restarted its filter (an accepted proposal, or a switch during probation)."""
        self._distrusted = False
        self._reset()
        # The re-initialised filter starts a new peak history (one training sample so far).
        self._reference = None

    def _reset(self) -> None:
        self._omega = self.params.omega
        self._eta_d = self.params.accept_peak
        self._failed_frames = 0
