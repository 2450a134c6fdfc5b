"""Where the decision filter looks while the target is lost: a budgeted lattice search (pure parts).

Conventions: offsets in target sides sqrt(w*h) from the last confident centre, positions in full-frame
pixels (x right, y down), scores are raw decision-filter peaks (MATLAB FFT convention, as eta_d).

The lattice holds window centres at stride x (i, j) != (0, 0) (the centre window is the core's own
detection sample, scored apart) within a square of side area + stride, nearest ring first. The cycle:
the centre's turned windows, then ring by ring its upright windows followed (first `turned_rings` rings
only) by its turned ones. Each lost frame scores the next entries of the cycle worth `windows_per_frame`
units (an upright window 1, a turned one `turned_window_cost`: it warps and extracts alone); the area grows
per lost frame (the paper's omega), so farther rings join as the loss goes on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from jsar.redetect.params import AcceptParams, SearchParams

RECENTRE_SIDES = 0.5  # a candidate this far (target sides) from its window's centre is worth a centred look


@dataclass(frozen=True)
class Candidate:
    """A place the decision filter scored: response peak position (x, y) px and raw peak."""

    x: float
    y: float
    score: float
    angle_deg: float = 0.0  # the window was scored with the image turned by this (0: upright)
    window_xy: tuple[float, float] | None = None  # centre (px) of the window that found it (None: unknown)

    def distance_sides(self, other_xy: tuple[float, float], side_px: float) -> float:
        """Distance to other_xy (px) in target sides."""
        return math.hypot(self.x - other_xy[0], self.y - other_xy[1]) / side_px

    def off_centre_sides(self, side_px: float) -> float:
        """How far the peak lies from the centre of its window, in target sides (inf: window unknown)."""
        return math.inf if self.window_xy is None else self.distance_sides(self.window_xy, side_px)


def track_velocity(track: list[tuple[int, float, float]]) -> tuple[float, float]:
    """Mean velocity (vx, vy) px per frame over committed (frame index, x px, y px) rows, oldest first
    ((0, 0) with fewer than two)."""
    if len(track) < 2:
        return 0.0, 0.0
    (first_index, x0, y0), (index, x, y) = track[0], track[-1]
    frames = index - first_index
    return (x - x0) / frames, (y - y0) / frames


def predicted_centre(track: list[tuple[int, float, float]], frame_index: int, max_frames: int) -> tuple[float, float]:
    """Constant-velocity prediction (px) for `frame_index` from the last committed (frame index, x px,
    y px) rows (oldest first): the last centre moved by the mean velocity over the rows for at most
    max_frames frames past the last row (the last centre itself with fewer than two rows)."""
    index, x, y = track[-1]
    if len(track) < 2 or max_frames <= 0:
        return x, y
    vx, vy = track_velocity(track)
    steps = min(frame_index - index, max_frames)
    return x + vx * steps, y + vy * steps


def gate_reach(speed_sides: float, lost_frames: int, accept: AcceptParams) -> float:
    """The motion gate's radius (target sides) after `lost_frames` for a target last moving at
    speed_sides per frame: base + speed_factor x max(speed, min_speed) x lost_frames."""
    return accept.gate_base_sides + accept.gate_speed_factor * max(speed_sides, accept.gate_min_speed) * lost_frames


def track_speed(track: list[tuple[int, float, float]], side_px: float) -> float:
    """Mean speed (target sides per frame) over committed (frame index, x px, y px) rows, oldest first (0 with one)."""
    if len(track) < 2:
        return 0.0
    (i0, x0, y0), (i1, x1, y1) = track[0], track[-1]
    return math.hypot(x1 - x0, y1 - y0) / (i1 - i0) / side_px


def lattice_offsets(area_sides: float, stride_sides: float) -> np.ndarray:
    """(K, 2) window offsets (dx, dy) in target sides: stride x (i, j) != (0, 0) with
    max(|dx|, |dy|) <= (area + stride) / 2, ordered by ring (Chebyshev distance), then angle."""
    rings = int(math.floor((area_sides + stride_sides) / 2.0 / stride_sides + 1e-9))
    if rings < 1:
        return np.empty((0, 2))
    steps = np.arange(-rings, rings + 1)
    i, j = (v.ravel() for v in np.meshgrid(steps, steps))
    keep = (i != 0) | (j != 0)
    i, j = i[keep], j[keep]
    order = np.lexsort((np.arctan2(j, i), np.maximum(np.abs(i), np.abs(j))))
    return np.column_stack([i[order], j[order]]).astype(np.float64) * stride_sides


def search_cycle(area_sides: float, stride_sides: float, angles_deg: tuple[float, ...],
                 turned_rings: int) -> np.ndarray:
    """(K, 3) lattice entries (dx, dy target sides, angle degrees): the centre (0, 0) at each turned
    angle, then per ring (lattice_offsets' order) its upright windows, then, for the first
    turned_rings rings, the ring at each angle."""
    offsets = lattice_offsets(area_sides, stride_sides)
    rings = np.max(np.abs(offsets), axis=1) if len(offsets) else np.empty(0)
    entries = [np.array([[0.0, 0.0, a] for a in angles_deg]).reshape(-1, 3)]
    for ring in np.unique(np.rint(rings / stride_sides)):
        at_ring = offsets[np.rint(rings / stride_sides) == ring]
        for angle in (0.0, *(angles_deg if ring <= turned_rings else ())):
            entries.append(np.column_stack([at_ring, np.full(len(at_ring), angle)]))
    return np.vstack(entries)


def power(base: float, exponent: int) -> float:
    """base ** exponent, inf where that is beyond a float (a search's growth or decay after hours lost: 1.05 ** n
    overflows from about 14,550 lost frames, 8 minutes at 30 fps)."""
    try:
        return base ** exponent
    except OverflowError:
        return math.inf


def decayed_bar(reference: float | None, lost_frames: int, accept: AcceptParams, min_peak: float = 0.0,
                fraction: float | None = None) -> float:
    """The acceptance bar (raw peak) after `lost_frames` failed frames: max(peak / decay^t,
    reference x max(floor, fraction / decay^t), min_peak), fraction = fraction unless given
    (reference None: the absolute part alone, or inf when that is 0: nothing to compare with yet)."""
    decay = power(accept.decay, lost_frames)
    start = accept.fraction if fraction is None else fraction
    relative = reference * max(accept.floor, start / decay) if reference is not None else 0.0
    bar = max(accept.peak / decay, relative)
    # Nothing to compare with: no absolute part and no reference (not a bar decayed to 0 after hours lost).
    return max(bar, min_peak) if accept.peak > 0 or relative > 0 else math.inf


@dataclass
class LossSearch:
    """The state of one search: around `anchor_xy` px for a target of `side_px`, since `lost_frames`.

    `windows(frame_wh)` gives this frame's lattice windows (centres px, angles) and advances the cycle;
    `decide(candidates, bar)` keeps or confirms a pending candidate and says when one is taken."""

    anchor_xy: tuple[float, float]
    side_px: float
    lattice: SearchParams
    accept: AcceptParams
    lost_frames: int = 0
    cursor: int = 0
    pending: Candidate | None = None
    lead: Candidate | None = None  # this frame's best candidate off its window's centre: next frame centres a window on it
    confirmations: int = 0
    core_agreements: int = 0  # consecutive lost frames on which the core's own way out passed its tests
    scored_windows: int = field(default=0)
    reach_sides: float = math.inf  # the motion gate's radius this frame (target sides from anchor_xy)
    refuted: list[Candidate] = field(default_factory=list)  # re-acquisitions of this search that did not hold
    coasting: bool = False  # the core followed its own detection on the last lost frame
    coasted_frames: int = 0  # lost frames of this search on which the core coasted

    def area_sides(self) -> float:
        """Side of the searched square (target sides) on the current lost frame (paper's omega)."""
        s = self.lattice
        return min(s.area_start_sides * power(s.area_growth, max(self.lost_frames - 1, 0)), s.area_max_sides)

    def windows(self, frame_wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """This frame's lattice windows: (M, 2) centres px and (M,) angles in degrees (0: upright), the next
        entries of search_cycle whose centre lies in the frame; advances the cycle. The entries taken cost
        at most windows_per_frame units (an upright entry 1, a turned one turned_window_cost; coast_window_cost
        fewer while the core coasts, as it did on the last lost frame), and at least one entry is taken while
        any unit is left (the cycle never stalls on a turned entry); at most one cycle."""
        entries = search_cycle(self.area_sides(), self.lattice.stride_sides, self.lattice.turned_angles_deg,
                               self.lattice.turned_rings)
        # A coasting frame's commit takes part of the frame's budget: a lost frame's cost stays bounded.
        spent = self.lattice.coast_window_cost if self.coasting else 0
        budget = max(self.lattice.windows_per_frame - spent, 0)
        if budget == 0 or len(entries) == 0:
            return np.empty((0, 2)), np.empty(0)
        order = (self.cursor + np.arange(len(entries))) % len(entries)
        costs = np.where(entries[order, 2] == 0, 1, self.lattice.turned_window_cost)
        count = max(int(np.searchsorted(np.cumsum(costs), budget, side="right")), 1)
        picked = entries[order[:count]]
        self.cursor = (self.cursor + count) % len(entries)
        centres = np.asarray(self.anchor_xy) + picked[:, :2] * self.side_px
        inside = ((centres[:, 0] >= 0) & (centres[:, 0] < frame_wh[0])
                  & (centres[:, 1] >= 0) & (centres[:, 1] < frame_wh[1]))
        self.scored_windows += int(inside.sum())
        return centres[inside], picked[inside, 2]

    def refuted_bar(self, candidate: Candidate) -> float:
        """refute_margin x the best refuted score within confirm_radius_sides of `candidate` (0: none)."""
        near = [r.score for r in self.refuted
                if candidate.distance_sides((r.x, r.y), self.side_px) <= self.accept.confirm_radius_sides]
        return self.accept.refute_margin * max(near) if near else 0.0

    def within_gate(self, candidate: Candidate) -> bool:
        """Whether `candidate` lies within the motion gate (reach_sides of anchor_xy): only then may it be taken."""
        return candidate.distance_sides(self.anchor_xy, self.side_px) <= self.reach_sides

    def may_take(self, candidate: Candidate) -> bool:
        """Whether `candidate` could be taken on this frame at some bar: within the gate and beating any refuted
        place near it (refuted_bar)."""
        return self.within_gate(candidate) and candidate.score >= self.refuted_bar(candidate)

    def decide(self, candidates: list[Candidate], bar: float, check: Callable[[Candidate], bool] | None = None,
               bar_for: Callable[[Candidate], float] | None = None) -> Candidate | None:
        """The candidate taken on this frame, or None; the best candidate found at least RECENTRE_SIDES
        off its window's centre becomes the lead (a lattice window rarely centres the target, and scores
        it lower the farther off: the next frame looks again centred on it, at its angle).
        A candidate above `bar` becomes pending; it is
        taken once a candidate above the bar lies within confirm_radius_sides of the pending one on
        confirm_frames consecutive frames (the pending one moves along with it). No candidate is
        taken in the first holdoff_frames lost frames, nor beyond reach_sides of anchor_xy, nor near a
        refuted re-acquisition unless it beats refute_margin x that one's score. `check` (optional) is a
        further test a candidate must pass to count as above the bar; it is asked only of candidates
        that passed the others. `bar_for` (optional) gives a candidate a bar of its own in place of `bar`."""
        # The lead is the best candidate found off its window's centre: a window scores a target off its
        # centre low (the cosine window), one centred on it tells its real score. A candidate already
        # centred is known; re-centring on it again would let one look-alike hold the lead for good.
        off_centre = [c for c in candidates if c.off_centre_sides(self.side_px) >= RECENTRE_SIDES]
        self.lead = max(off_centre, key=lambda c: c.score) if off_centre else None
        above = [c for c in candidates if c.score >= (bar if bar_for is None else bar_for(c)) and self.may_take(c)
                 and (check is None or check(c))]
        if self.pending is not None:
            near = [c for c in above if c.distance_sides((self.pending.x, self.pending.y), self.side_px)
                    <= self.accept.confirm_radius_sides]
            if near:
                self.pending = max(near, key=lambda c: c.score)
                self.confirmations += 1
            else:
                self.pending, self.confirmations = None, 0
        if self.pending is None and above:
            self.pending, self.confirmations = max(above, key=lambda c: c.score), 0
        if (self.pending is not None and self.confirmations >= self.accept.confirm_frames
                and self.lost_frames > self.accept.holdoff_frames):
            return self.pending
        return None
