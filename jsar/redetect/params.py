"""JSAR-Re's parameters: one nested, typed set with one default per value (the core's are jsar.config.JsarParams).

Groups by the part that uses them: `monitor` (confident, reliable, loss), `search` (where the decision filter
looks while lost), `accept` (when a candidate is taken), `colour` (the colour checks), `verify` (the learnt
verifier). Peaks are raw responses in the MATLAB FFT convention (jsar.config), the unit of the paper's zeta_e,
zeta_s and eta_d; distances in target sides sqrt(w*h) unless a name says px. Why each value: docs/method.md.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

from jsar.checked import (Relation, at_least, at_least_key, at_most_key, below_key, check_fields, checked, interval,
                          non_negative, one_of, positive, with_overrides)

InsideRule = Literal["full", "centre"]
Reacquire = Literal["relocate", "retrain"]

UNIT = interval(0, 1, low_open=True)  # a rate or fraction in (0, 1]
FRACTION = interval(0, 1)  # [0, 1]
COSINE = interval(-1, 1)


def _turned_angles(angles: tuple[float, ...]) -> str | None:
    if all(-180 < a <= 180 and a != 0 for a in angles):
        return None
    return f"must be angles in (-180, 180] other than 0 (degrees), got {angles}"


def _some_bar(peak: float, accept: Any) -> str | None:
    return None if peak > 0 or accept.fraction > 0 else "and fraction cannot both be 0 (every candidate would pass)"


@dataclass(frozen=True)
class MonitorParams:
    """Failure monitor (monitor.py): when a frame is confident, reliable, or may be a loss."""

    confident_peak: float = checked(0.0105, positive, at_most_key("reliable_peak"))  # zeta_e: a frame at or below it is not confident (raw peak; the authors' code 0.01)
    reliable_peak: float = checked(0.013, positive)  # zeta_s: the decision filter learns frames above it (raw peak; paper)
    relative_drop: float = checked(0.6, interval(0, 1, high_open=True))  # not confident either at or below this x the running reference of reliable peaks (0: paper's rule only)
    reference_rate: float = checked(0.1, UNIT)  # the running reference's (and the decision filter's) update rate towards a higher peak
    reference_fall_rate: float = checked(0.02, UNIT)  # its rate towards a lower peak (slow: a gradual occlusion must not drag it down)
    warmup_frames: int = checked(30, non_negative)  # no loss is declared before this frame (the authors' "after frame 30")
    min_area_px2: float = checked(16.0, non_negative, below_key("max_area_px2"))  # a loss is declared only for a box area above this (px^2)
    max_area_px2: float = 20000.0  # a loss is declared only for a box area below this (px^2)
    inside_rule: InsideRule = checked("full", one_of("full", "centre"))  # a loss is declared only for a box inside the image: "full" (the whole box) or "centre" (its centre)

    def validate(self, prefix: str = "monitor") -> None:
        """ValueError naming `prefix.key` of the first invalid value."""
        check_fields(self, prefix)


@dataclass(frozen=True)
class SearchParams:
    """Where the decision filter looks while the target is lost (search.py); the lattice schedule: docs/method.md."""

    area_start_sides: float = checked(5.0, positive)  # omega_0: side of the searched square on the first lost frame (target sides; paper)
    area_growth: float = checked(1.05, at_least(1))  # omega's growth factor per lost frame (paper)
    area_max_sides: float = checked(15.0, at_least_key("area_start_sides"))  # omega's bound (target sides; the paper lets it grow without bound)
    stride_sides: float = checked(2.5, positive)  # lattice stride (target sides): half a 5-side window
    windows_per_frame: int = checked(8, non_negative)  # a lost frame's window budget in units of an upright window (0: the core's sample only): its cost
    coast_window_cost: int = checked(3, non_negative)  # windows_per_frame units a lost frame gives up while the core coasts (its commit is about 3 windows' work; 0: none)
    turned_window_cost: int = checked(2, at_least(1))  # windows_per_frame units a turned window takes (an upright one takes 1): its warp and features are its own
    turned_angles_deg: tuple[float, ...] = checked((45.0, -45.0), _turned_angles)  # angles (degrees) windows are also scored turned by: a car that turned while hidden
    turned_rings: int = checked(2, non_negative)  # lattice rings (after the centre) scored turned too; farther rings upright only
    turned_score_factor: float = checked(0.9, UNIT)  # a turned window's score is multiplied by this: an upright match keeps the pre-loss filters
    coast_radius_sides: float = checked(0.5, non_negative)  # while lost the core commits its detection within this of the predicted centre (target sides; 0: never)
    coast_unless_other: bool = False  # ... and not where the verifier calls the core's box another object (a coast on still ground holds the prediction on itself)
    coast_after_drift: bool = False  # a drift or appearance loss may coast too (its core sits where the target was judged absent)
    coast_learns_size: bool = True  # a coasting commit trains the size filter (False: it estimates the size only, learning nothing of a hidden target's size)
    coast_max_frames: int = checked(30, non_negative)  # lost frames one loss's core may coast at most, then it waits at the prediction (0: no bound)
    motion_frames: int = checked(5, at_least(2))  # committed frames the target's velocity is measured over
    focus_follows_motion: bool = True  # the window on the pending candidate (or the lead) is centred where it moved to since the last frame, at the track's mean velocity (False: on the candidate)
    predict_max_frames: int = checked(3, non_negative)  # lost frames the search centre follows that velocity for, then holds (0: the last centre)

    def validate(self, prefix: str = "search") -> None:
        """ValueError naming `prefix.key` of the first invalid value."""
        check_fields(self, prefix)


@dataclass(frozen=True)
class AcceptParams:
    """When a candidate is taken and what taking it does; bar = max(peak / decay^t, reference x max(floor,
    fraction / decay^t)) after t failed frames (search.decayed_bar; the schedule's reasons: docs/method.md)."""

    peak: float = checked(0.0, non_negative, Relation(_some_bar))  # eta_d's absolute part (raw peak; paper 0.02; 0: relative only)
    fraction: float = checked(0.625, FRACTION)  # the bar's start relative to the decision filter's reference (0: the paper's absolute eta_d only)
    decay: float = checked(1.005, at_least(1))  # the bar is divided by this per lost frame (the paper's eta_d decay)
    floor: float = checked(0.45, non_negative, at_most_key("fraction"))  # the relative bar never falls below this x the reference
    core_fraction: float = checked(0.5, at_least_key("floor"), interval(0, 1))  # the relative bar's start for the core's own detection, confident again there
    confirm_frames: int = checked(1, non_negative)  # a candidate is taken after passing the bar on this many more frames nearby
    core_confirm_frames: int = checked(2, at_least(1))  # the core's own way out needs its tests passed on this many lost frames in a row
    confirm_radius_sides: float = checked(1.5, positive)  # "nearby" for confirmation, the coasting core and refuted places (target sides)
    holdoff_frames: int = checked(5, non_negative)  # no candidate is taken on the first this-many lost frames
    reacquire: Reacquire = checked("relocate", one_of("relocate", "retrain"))  # taking moves the pre-loss filters ("relocate") or retrains from the frame ("retrain", paper)
    gate_base_sides: float = checked(1.5, non_negative)  # motion gate's base radius around the predicted centre (target sides; inf: no gate)
    gate_speed_factor: float = checked(3.0, non_negative)  # the gate's radius grows by this x the target's speed (sides per frame) per lost frame
    gate_min_speed: float = checked(0.05, non_negative)  # the speed the gate assumes at least (target sides per frame)
    switch_margin: float = checked(1.3, at_least(1))  # while the core coasts, a candidate away from it must score this x the core's score
    probation_frames: int = checked(10, non_negative)  # a re-acquisition lost again within this many committed frames is refuted (0: never)
    refute_margin: float = checked(1.2, at_least(1))  # a candidate near a refuted place must score this x the refuted one
    size_hold_fraction: float = checked(0.75, interval(0, 1, high_open=True))  # after a take the size is held until the size filter peaks at this x its mean (0: no hold)

    def validate(self, prefix: str = "accept") -> None:
        """ValueError naming `prefix.key` of the first invalid value."""
        check_fields(self, prefix)


@dataclass(frozen=True)
class ColourParams:
    """The colour checks (colour_check.py): a candidate's match to the target's colours, and the drift check."""

    min_match: float = checked(0.9, FRACTION)  # a candidate's box must match the target's colours this x as well as the tracked target did (0: no check)
    core_min_match: float = checked(0.75, FRACTION)  # the same for the core's own way out (0: no check there)
    bins: int = checked(8, interval(2, 32))  # histogram levels per channel (8: 512 bins for a colour frame)
    surround_scale: float = checked(2.0, interval(1, float("inf"), low_open=True))  # the surround is the box enlarged this many times per side
    rate: float = checked(0.05, UNIT)  # histogram learning rate on the frames the decision filter learns
    reference_rate: float = checked(0.1, UNIT)  # learning rate of the match's running means on the learnt boxes
    anchor_inner: float = checked(0.6, UNIT)  # the drift check's colours: the central this fraction of the selected box's width and height
    anchor_min_share: float = checked(0.6, FRACTION)  # the drift check is used only if those colours cover this share of it at selection
    drift_share: float = checked(0.1, interval(0, 1, high_open=True))  # a box with less than this x the selection's share of them is drifting (0: no drift check)
    drift_frames: int = checked(10, at_least(1))  # tracked frames in a row drifting that make a loss; a way out needs the share >= drift_share
    clear_share: float = checked(0.5, at_least_key("drift_share"))  # a box with at least this share clearly shows the target (checkpoints, lower bar)
    checkpoint_frames: int = checked(10, at_least(1))  # at most one checkpoint per this many frames (a drift loss rolls back to the last)
    clear_bar_fraction: float = checked(0.7, UNIT)  # a lost candidate whose box clearly shows the target needs this x the bar (1: no change)

    def validate(self, prefix: str = "colour") -> None:
        """ValueError naming `prefix.key` of the first invalid value."""
        check_fields(self, prefix)


@dataclass(frozen=True)
class VerifyParams:
    """The verifier (appearance.py): a learnt embedding's check of candidates while lost; cosines -1..1."""

    enabled: bool = True  # on: the verifier judges candidates (docs/method.md, "The verifier")
    min_similarity: float = checked(0.6, COSINE, at_least_key("reject_similarity"))  # "target": cosine to the target memory at least this, and margin above the look-alikes'
    margin: float = checked(0.05, interval(0, 2))  # "target" needs the cosine to the target memory this above the cosine to the look-alike memory
    reject_similarity: float = checked(0.55, COSINE)  # "other": cosine to the target memory under this
    reject_nearer_other: bool = True  # "other" also needs a look-alike at least as near as the target memory (a turned target unlike both stays "unsure")
    bar_fraction: float = checked(0.6, UNIT)  # a "target" candidate's bar: this x the acceptance bar (1: no lower bar)
    over_colour_match: bool = True  # a "target" candidate needs no colour-model match (the selection's colours still)
    target_slots: int = checked(6, at_least(1))  # target memory: the selection plus this many minus one recent reliable frames
    anchor_similarity: float = checked(0.5, COSINE)  # a reliable frame's look joins the target memory only at least this near the selection's (cosine; -1: no bound)
    selection_floor: float = checked(-1.0, COSINE)  # a watch check, the core's own way out of a loss, or a take in a loss the watch began, whose look is under this cosine to the selection's counts as another object, whatever the memories say (a slide the target memory learnt along; -1: off)
    learn_frames: int = checked(10, at_least(1))  # the verifier learns one reliable frame in this many, with the look-alikes around it
    other_slots: int = checked(32, non_negative)  # look-alike memory size (oldest out first)
    ring_sides: float = checked(2.0, positive)  # look-alike windows' distance from the target (target sides)
    ring_count: int = checked(8, at_least(1))  # look-alike windows per learnt frame, at evenly spaced angles
    watch_frames: int = checked(3, non_negative)  # while tracking the box is checked once per this many frames (0: never)
    watch_count: int = checked(2, at_least(1))  # "other" on this many checks in a row is a loss (a confident slide)
    defer_frames: int = checked(3, non_negative)  # a tracked frame's learning and watch check (not on probation) take effect this many frames later: their embeddings can run on another thread meanwhile (0: at once)
    lost_looks: int = checked(2, non_negative)  # candidates the verifier looks at per lost frame at most, those near the pending one first, then by score; one not looked at is not taken on that frame (0: no bound)
    hold_verified: bool = True  # a take called the target when taken and on every check since is not refuted by a loss on probation: a new loss starts from it
    gate_map: bool = False  # whole-gate search: one network pass over the motion gate while lost
    gate_map_frames: int = checked(1, at_least(1))  # the whole-gate search runs on one lost frame in this many
    gate_map_cells: int = checked(3, at_least(1))  # the whole-gate search's target width in network feature cells (stride 16 px)
    gate_map_max_px: int = checked(320, at_least(64))  # the whole-gate search's region side at most (resized px; the gate is cut beyond)
    gate_map_peaks: int = checked(3, at_least(1))  # the whole-gate search's best this-many peaks become decision-filter windows
    gate_map_min_cosine: float = checked(0.5, COSINE)  # a whole-gate peak must match the target's template at least this well (cosine)

    def validate(self, prefix: str = "verify") -> None:
        """ValueError naming `prefix.key` of the first invalid value."""
        check_fields(self, prefix)


@dataclass(frozen=True)
class RedetectParams:
    """Everything JSAR-Re adds to JSAR: monitor, search, acceptance, colour checks, verifier (see their classes)."""

    monitor: MonitorParams = field(default_factory=MonitorParams)
    search: SearchParams = field(default_factory=SearchParams)
    accept: AcceptParams = field(default_factory=AcceptParams)
    colour: ColourParams = field(default_factory=ColourParams)
    verify: VerifyParams = field(default_factory=VerifyParams)

    def validate(self, prefix: str = "redetect") -> None:
        """ValueError naming the first invalid key as prefix.group.key."""
        check_fields(self, prefix)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None, prefix: str = "redetect") -> "RedetectParams":
        """Defaults with nested overrides {group: {key: value}}; ValueError naming prefix.group.key."""
        if mapping is None:
            return cls()
        if not isinstance(mapping, Mapping):
            raise ValueError(f"{prefix} must be a mapping of groups (monitor, search, accept, colour, verify), got {mapping!r}")
        return cls().with_overrides(prefix, **mapping)

    def with_overrides(self, prefix: str = "redetect", **groups: Any) -> "RedetectParams":
        """A copy with {group: {key: value}} overrides applied and checked (the ablation's switch)."""
        known = [f.name for f in dataclasses.fields(self)]
        for group in groups:
            if group not in known:
                raise ValueError(f"unknown key {prefix}.{group}; expected one of {', '.join(known)}")
        params = dataclasses.replace(self, **{group: with_overrides(getattr(self, group), values, f"{prefix}.{group}")
                                              for group, values in groups.items()})
        params.validate(prefix)
        return params
