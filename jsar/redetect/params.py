"""JSAR-Re's parameters: one nested, typed set with one default per value.

The core tracker's parameters (features, filters, size filter) stay in `jsar.config.JsarParams`;
everything JSAR-Re adds lives here, grouped by the part that uses it:

- `monitor`: when a frame is confident (commit), reliable (train the decision filter), or a loss;
- `search`: where the decision filter looks while the target is lost, and how much per frame;
- `accept`: when a candidate is taken, and what taking it does;
- `colour`: the colour check a candidate must also pass to be taken.

Thresholds on response peaks are raw values in the MATLAB FFT convention (see jsar.config), the
unit of the paper's zeta_e, zeta_s and eta_d; distances and areas are in target sides sqrt(w*h)
unless a name says px. `RedetectParams.from_mapping` builds a set from nested dicts (jsar.create,
the service's config.yaml) and names the offending key, e.g. `redetect.search.windows_per_frame`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

InsideRule = Literal["full", "centre"]
Reacquire = Literal["relocate", "retrain"]


@dataclass(frozen=True)
class MonitorParams:
    """Failure monitor (monitor.py): confident, reliable, eligible; peaks in raw response units."""

    confident_peak: float = 0.0105  # zeta_e: a frame below it is not confident (paper; the authors' code 0.01)
    reliable_peak: float = 0.013  # zeta_s: the decision filter trains on frames above it (paper)
    relative_drop: float = 0.6  # not confident either below this x the running reference (0: paper's rule only)
    reference_rate: float = 0.1  # running reference's update rate towards a higher peak
    reference_fall_rate: float = 0.02  # ... towards a lower one (slow: a gradual occlusion must not drag it)
    warmup_frames: int = 30  # no loss is declared before this frame (the authors' "after frame 30")
    min_area_px2: float = 16.0  # losses are declared only for min_area < w*h < max_area (px^2)
    max_area_px2: float = 20000.0
    inside_rule: InsideRule = "full"  # ... and for a box wholly inside the image ("centre": its centre)

    def validate(self, prefix: str = "monitor") -> None:
        """Raise ValueError naming `prefix.key` of the first invalid value."""
        _require(prefix, "confident_peak", 0 < self.confident_peak <= self.reliable_peak,
                 f"0 < confident_peak <= reliable_peak, got {self.confident_peak}, {self.reliable_peak}")
        _require(prefix, "relative_drop", 0 <= self.relative_drop < 1, f"0 <= value < 1, got {self.relative_drop}")
        for key in ("reference_rate", "reference_fall_rate"):
            value = getattr(self, key)
            _require(prefix, key, 0 < value <= 1, f"0 < value <= 1, got {value}")
        _require(prefix, "warmup_frames", self.warmup_frames >= 0, f">= 0, got {self.warmup_frames}")
        _require(prefix, "min_area_px2", 0 <= self.min_area_px2 < self.max_area_px2,
                 f"0 <= min_area_px2 < max_area_px2, got {self.min_area_px2}, {self.max_area_px2}")
        _require(prefix, "inside_rule", self.inside_rule in ("full", "centre"),
                 f"'full' or 'centre', got {self.inside_rule!r}")


@dataclass(frozen=True)
class SearchParams:
    """Where the decision filter looks while the target is lost (search.py).

    Windows are the decision filter's own sample geometry (a square of search_area_factor target
    sides, at the last confident size) centred on a square lattice of stride `stride_sides` around
    the last confident centre, nearest rings first, within a square of side `area_sides` (the
    paper's omega: area_start, x area_growth per lost frame, up to area_max). The centre moves on
    with the target's last velocity (constant, for at most predict_max_frames lost frames), so a
    target lost while moving fast is looked for where it went. The window on that centre (upright)
    is the core tracker's own detection sample, scored every lost frame at no extra feature cost.
    While lost, the core coasts: it commits its own detection (as plain JSAR; the decision filter
    learns nothing) when that lies within `coast_radius_sides` of the predicted centre, else it waits
    at the prediction.
    The centre's window and the lattice windows of the first `turned_rings` rings are also scored with
    the image turned by each of `turned_angles_deg` (a car that turned at a junction or under a bridge
    no longer matches the filter's gradient orientations), its score x turned_score_factor; farther
    rings are scored upright only (a target that turned did so where it was lost, and turned windows on
    every ring made the cycle three times as long). `windows_per_frame` of these
    windows (upright or turned) are scored per lost frame, cycling through them ring by ring
    (search.search_cycle): the per-frame budget that bounds a lost frame's cost."""

    area_start_sides: float = 5.0  # omega_0 (paper)
    area_growth: float = 1.05  # omega *= this per lost frame (paper)
    area_max_sides: float = 15.0  # the paper lets omega grow without bound
    stride_sides: float = 2.5  # lattice stride (target sides): half a 5-side window
    windows_per_frame: int = 6  # budget: windows (upright or turned) per lost frame (0: the core's window only)
    turned_angles_deg: tuple[float, ...] = (45.0, -45.0)  # every window also scored turned by these ...
    turned_rings: int = 2  # ... on the centre and this many lattice rings around it (farther: upright only)
    turned_score_factor: float = 0.9  # ... its score x this (an upright match should win: it keeps the pre-loss filters)
    coast_radius_sides: float = 0.5  # while lost the core follows its detection (as plain JSAR) within this of the prediction (0: never)
    motion_frames: int = 5  # the search follows the target's velocity over its last this-many committed frames ...
    predict_max_frames: int = 3  # ... for at most this many lost frames, then holds (0: the last centre)

    def validate(self, prefix: str = "search") -> None:
        """Raise ValueError naming `prefix.key` of the first invalid value."""
        _require(prefix, "area_start_sides", self.area_start_sides > 0, f"> 0, got {self.area_start_sides}")
        _require(prefix, "area_growth", self.area_growth >= 1, f">= 1, got {self.area_growth}")
        _require(prefix, "area_max_sides", self.area_max_sides >= self.area_start_sides,
                 f">= area_start_sides, got {self.area_max_sides} < {self.area_start_sides}")
        _require(prefix, "stride_sides", self.stride_sides > 0, f"> 0, got {self.stride_sides}")
        _require(prefix, "windows_per_frame", self.windows_per_frame >= 0, f">= 0, got {self.windows_per_frame}")
        _require(prefix, "turned_angles_deg", all(-180 < a <= 180 and a != 0 for a in self.turned_angles_deg),
                 f"angles in (-180, 180] other than 0 (degrees), got {self.turned_angles_deg}")
        _require(prefix, "turned_rings", self.turned_rings >= 0, f">= 0, got {self.turned_rings}")
        _require(prefix, "turned_score_factor", 0 < self.turned_score_factor <= 1,
                 f"0 < value <= 1, got {self.turned_score_factor}")
        _require(prefix, "coast_radius_sides", self.coast_radius_sides >= 0, f">= 0, got {self.coast_radius_sides}")
        _require(prefix, "motion_frames", self.motion_frames >= 2, f">= 2, got {self.motion_frames}")
        _require(prefix, "predict_max_frames", self.predict_max_frames >= 0, f">= 0, got {self.predict_max_frames}")


@dataclass(frozen=True)
class AcceptParams:
    """When a candidate is taken (its decision-filter score) and what taking it does.

    bar = max(peak / decay^t, reference x max(floor, fraction /
    decay^t)) after t failed frames, reference = the running mean of the decision filter's
    peaks on the frames it learnt. The paper's eta_d is the absolute peak (0.02) decaying by
    1.005 per failed frame. Relative to how the target scored, the bar starts high (right after a
    loss the nearest thing to score is the occluder, or the background where the target was) and
    relaxes to floor as the loss goes on (the target may come back changed): 0.625x at the first
    lost frame, 0.5x after 45, 0.45x from 66 on. Most false re-acquisitions come early in a loss (the
    occluder where the target was, a look-alike nearby); a target that comes back changed after a long
    loss (the closed loop's car out of the bridge, turned, ~0.5x) needs the low floor. The core's own
    detection, confident again where the decision filter peaks, passes two tests: its bar starts from
    core_fraction instead (0.5x; with 0.625x a wakeboarder's false loss on Surfing06 lasted until a
    candidate beside him was taken). It ends the loss once it passed them on `core_confirm_frames`
    consecutive lost frames (a core confident for a single frame at a wrong place, e.g. a tiny box
    flickering at the frame's edge, claimed the target again and again). A candidate is taken after it passes the bar on
    `confirm_frames` consecutive frames within `confirm_radius_sides` of where it was. Taking it
    either moves the core tracker there with its filters as they were before the loss ("relocate":
    nothing was learnt while lost) or retrains them from that one frame ("retrain", the paper).
    `holdoff_frames`: no candidate is taken on the first this-many lost frames. The motion gate: a
    candidate farther from the predicted centre than gate_base + gate_speed_factor x speed x lost
    frames (target sides; speed = the target's last speed in sides per frame, at least
    gate_min_speed) is not taken: a look-alike nearby is not where the target can be yet.
    While the core coasts (SearchParams.coast_radius_sides), a candidate farther than
    confirm_radius_sides from the core's detection must also score `switch_margin` x the decision
    filter's score on that detection.
    A re-acquisition from a loss that is lost again within `probation_frames` did not hold: the
    search it ended resumes (the tracker as it was before it), and a candidate near the refuted
    place must score refute_margin x what the refuted one scored.
    `size_hold_fraction`: after a candidate is taken the core keeps its size until its size filter's
    response peak is back to this x the running mean of its peaks (JsarTracker.hold_size_until_recognised;
    0: no hold): judged by the size model of its old look, a target that came back turned had its box
    widen by ~2 % a frame to twice the car's width (the closed loop's car after the bridge)."""

    peak: float = 0.0  # eta_d, absolute part (paper 0.02; 0: relative only)
    fraction: float = 0.625  # relative part at the first lost frame (0: the paper's absolute eta_d only) ...
    decay: float = 1.005  # ... divided by this per lost frame (paper's value, there on the absolute eta_d) ...
    floor: float = 0.45  # ... down to this
    core_fraction: float = 0.5  # ... from this instead for the core's own detection, confident again there
    confirm_frames: int = 1
    core_confirm_frames: int = 2  # the core's own way out needs its tests passed on this many consecutive lost frames
    confirm_radius_sides: float = 1.5
    holdoff_frames: int = 5
    reacquire: Reacquire = "relocate"
    gate_base_sides: float = 1.5  # a candidate must lie within base + speed_factor x speed x lost frames ...
    gate_speed_factor: float = 3.0  # ... target sides of the predicted centre, speed in sides per frame ...
    gate_min_speed: float = 0.05  # ... at least this (inf base: no gate)
    switch_margin: float = 1.3
    probation_frames: int = 10  # a re-acquisition lost again within this many frames is refuted (0: never) ...
    refute_margin: float = 1.2  # ... and its place must then score this x its score to be taken again
    size_hold_fraction: float = 0.75  # after a take the size is kept until the size filter peaks at this x its mean (0: no hold)

    def validate(self, prefix: str = "accept") -> None:
        """Raise ValueError naming `prefix.key` of the first invalid value."""
        _require(prefix, "peak", self.peak >= 0, f">= 0, got {self.peak}")
        _require(prefix, "fraction", 0 <= self.fraction <= 1, f"0 <= value <= 1, got {self.fraction}")
        _require(prefix, "peak", self.peak > 0 or self.fraction > 0,
                 "peak and fraction cannot both be 0 (every candidate would pass)")
        _require(prefix, "decay", self.decay >= 1, f">= 1, got {self.decay}")
        _require(prefix, "floor", 0 <= self.floor <= self.fraction,
                 f"0 <= floor <= fraction, got {self.floor}, {self.fraction}")
        _require(prefix, "core_fraction", self.floor <= self.core_fraction <= 1,
                 f"floor <= core_fraction <= 1, got {self.core_fraction}, {self.floor}")
        _require(prefix, "confirm_frames", self.confirm_frames >= 0, f">= 0, got {self.confirm_frames}")
        _require(prefix, "core_confirm_frames", self.core_confirm_frames >= 1, f">= 1, got {self.core_confirm_frames}")
        _require(prefix, "confirm_radius_sides", self.confirm_radius_sides > 0, f"> 0, got {self.confirm_radius_sides}")
        _require(prefix, "holdoff_frames", self.holdoff_frames >= 0, f">= 0, got {self.holdoff_frames}")
        _require(prefix, "reacquire", self.reacquire in ("relocate", "retrain"),
                 f"'relocate' or 'retrain', got {self.reacquire!r}")
        _require(prefix, "switch_margin", self.switch_margin >= 1, f">= 1, got {self.switch_margin}")
        _require(prefix, "probation_frames", self.probation_frames >= 0, f">= 0, got {self.probation_frames}")
        _require(prefix, "refute_margin", self.refute_margin >= 1, f">= 1, got {self.refute_margin}")
        _require(prefix, "size_hold_fraction", 0 <= self.size_hold_fraction < 1,
                 f"0 <= value < 1, got {self.size_hold_fraction}")
        for key in ("gate_base_sides", "gate_speed_factor", "gate_min_speed"):
            value = getattr(self, key)
            _require(prefix, key, value >= 0, f">= 0, got {value}")


@dataclass(frozen=True)
class ColourParams:
    """The colour check on candidates (colour_check.py): a candidate that passed the acceptance bar (the
    core confident again included) is taken only if its box matches the target's colours at least
    `min_match` x as well as the tracked target's boxes did (`core_min_match` x for the core confident
    again where the decision filter peaks: two tests already agree there, and a false loss in plain view,
    the box half a side off, must end at once): the larger of its histogram's similarity
    to the target's and its share of pixels in the target's own colours (those likelier the target's
    than the surround's, the box enlarged surround_scale times per side), each over its running mean on
    the learnt boxes. Joint histograms of `bins` levels per channel, learnt on the frames the decision
    filter learns, blended in at `rate`; the running means follow at `reference_rate`."""

    min_match: float = 0.9  # relative to the tracked target (0: no check)
    core_min_match: float = 0.75  # ... for the core's own way out (0: no check there)
    bins: int = 8  # levels per channel (8: 512 bins for a colour frame)
    surround_scale: float = 2.0
    rate: float = 0.05
    reference_rate: float = 0.1
    anchor_inner: float = 0.6  # the drift check's colours: the central this fraction of the selected box's width and height
    anchor_min_share: float = 0.6  # ... used only if its own colours cover this share of it at selection (else no check)
    drift_share: float = 0.1  # tracking with the box's share of them below this x at selection ... (0: no drift check)
    drift_frames: int = 10  # ... on this many frames in a row is a loss; a way out of a loss needs the share >= drift_share
    clear_share: float = 0.5  # a box with the share >= this clearly shows the target: a tracked one is a checkpoint ...
    checkpoint_frames: int = 10  # ... (a drift loss rolls back to the last; one per this many frames) ...
    clear_bar_fraction: float = 0.7  # ... and a candidate's bar while lost is this x the acceptance bar (1: no change)

    def validate(self, prefix: str = "colour") -> None:
        """Raise ValueError naming `prefix.key` of the first invalid value."""
        _require(prefix, "min_match", 0 <= self.min_match <= 1, f"0 <= value <= 1, got {self.min_match}")
        _require(prefix, "core_min_match", 0 <= self.core_min_match <= 1, f"0 <= value <= 1, got {self.core_min_match}")
        _require(prefix, "bins", 2 <= self.bins <= 32, f"2 <= value <= 32, got {self.bins}")
        _require(prefix, "surround_scale", self.surround_scale > 1, f"> 1, got {self.surround_scale}")
        for key in ("rate", "reference_rate", "anchor_inner"):
            value = getattr(self, key)
            _require(prefix, key, 0 < value <= 1, f"0 < value <= 1, got {value}")
        _require(prefix, "anchor_min_share", 0 <= self.anchor_min_share <= 1,
                 f"0 <= value <= 1, got {self.anchor_min_share}")
        _require(prefix, "drift_share", 0 <= self.drift_share < 1, f"0 <= value < 1, got {self.drift_share}")
        _require(prefix, "drift_frames", self.drift_frames >= 1, f">= 1, got {self.drift_frames}")
        _require(prefix, "clear_share", self.clear_share >= self.drift_share,
                 f">= drift_share, got {self.clear_share} < {self.drift_share}")
        _require(prefix, "checkpoint_frames", self.checkpoint_frames >= 1, f">= 1, got {self.checkpoint_frames}")
        _require(prefix, "clear_bar_fraction", 0 < self.clear_bar_fraction <= 1,
                 f"0 < value <= 1, got {self.clear_bar_fraction}")


@dataclass(frozen=True)
class VerifyParams:
    """The verifier (appearance.py): a learnt embedding's check of candidates while lost; cosines -1..1."""

    enabled: bool = True  # off: the decision filter and colour check alone decide
    min_similarity: float = 0.6  # "target": cosine to the target memory at least this ...
    margin: float = 0.05  # ... and this above the cosine to the look-alike memory
    reject_similarity: float = 0.55  # "other": cosine to the target memory under this
    bar_fraction: float = 0.6  # a "target" candidate's bar: this x the acceptance bar (1: no lower bar) ...
    over_colour_match: bool = True  # ... and it needs no colour-model match (the selection's colours still)
    target_slots: int = 6  # target memory: the selection plus this many minus one recent reliable frames ...
    learn_frames: int = 10  # ... one per this many reliable frames, with the look-alikes around it
    other_slots: int = 32  # look-alike memory size (oldest out first)
    ring_sides: float = 2.0  # look-alikes: windows this many target sides from the target ...
    ring_count: int = 8  # ... at this many angles
    watch_frames: int = 3  # while tracking, the box is checked once per this many frames (0: never) ...
    watch_count: int = 2  # ... and "other" on this many checks in a row is a loss (a confident slide)
    gate_map: bool = False  # whole-gate search: one network pass over the motion gate while lost ...
    gate_map_frames: int = 1  # ... on one lost frame in this many ...
    gate_map_cells: int = 3  # ... the target this many feature cells across (stride 16) ...
    gate_map_max_px: int = 320  # ... the region at most this many resized px a side (the gate is cut beyond) ...
    gate_map_peaks: int = 3  # ... its best this-many peaks become windows of the decision filter ...
    gate_map_min_cosine: float = 0.5  # ... those matching the target's template at least this well

    def validate(self, prefix: str = "verify") -> None:
        """Raise ValueError naming `prefix.key` of the first invalid value."""
        _require(prefix, "min_similarity", -1 <= self.reject_similarity <= self.min_similarity <= 1,
                 f"-1 <= reject_similarity <= min_similarity <= 1, got {self.reject_similarity}, {self.min_similarity}")
        _require(prefix, "margin", 0 <= self.margin <= 2, f"0 <= value <= 2, got {self.margin}")
        _require(prefix, "bar_fraction", 0 < self.bar_fraction <= 1, f"0 < value <= 1, got {self.bar_fraction}")
        for key in ("target_slots", "learn_frames", "ring_count"):
            value = getattr(self, key)
            _require(prefix, key, value >= 1, f">= 1, got {value}")
        _require(prefix, "other_slots", self.other_slots >= 0, f">= 0, got {self.other_slots}")
        _require(prefix, "ring_sides", self.ring_sides > 0, f"> 0, got {self.ring_sides}")
        _require(prefix, "watch_frames", self.watch_frames >= 0, f">= 0, got {self.watch_frames}")
        for key in ("watch_count", "gate_map_frames", "gate_map_cells", "gate_map_peaks"):
            value = getattr(self, key)
            _require(prefix, key, value >= 1, f">= 1, got {value}")
        _require(prefix, "gate_map_max_px", self.gate_map_max_px >= 64, f">= 64, got {self.gate_map_max_px}")
        _require(prefix, "gate_map_min_cosine", -1 <= self.gate_map_min_cosine <= 1,
                 f"-1 <= value <= 1, got {self.gate_map_min_cosine}")


@dataclass(frozen=True)
class RedetectParams:
    """Everything JSAR-Re adds to JSAR: monitor, search, acceptance, colour check, verifier (see their classes)."""

    monitor: MonitorParams = field(default_factory=MonitorParams)
    search: SearchParams = field(default_factory=SearchParams)
    accept: AcceptParams = field(default_factory=AcceptParams)
    colour: ColourParams = field(default_factory=ColourParams)
    verify: VerifyParams = field(default_factory=VerifyParams)

    def validate(self, prefix: str = "redetect") -> None:
        """Raise ValueError naming the first invalid key as prefix.group.key."""
        self.monitor.validate(f"{prefix}.monitor")
        self.search.validate(f"{prefix}.search")
        self.accept.validate(f"{prefix}.accept")
        self.colour.validate(f"{prefix}.colour")
        self.verify.validate(f"{prefix}.verify")

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None, prefix: str = "redetect") -> "RedetectParams":
        """Defaults with nested overrides {group: {key: value}}; ValueError naming prefix.group.key."""
        params = cls()
        if mapping is None:
            return params
        if not isinstance(mapping, Mapping):
            raise ValueError(f"{prefix} must be a mapping of groups (monitor, search, accept, colour, verify), got {mapping!r}")
        groups = {f.name: getattr(params, f.name) for f in dataclasses.fields(cls)}
        replaced: dict[str, Any] = {}
        for group, values in mapping.items():
            if group not in groups:
                raise ValueError(f"unknown key {prefix}.{group}; expected one of {', '.join(groups)}")
            replaced[group] = _with_overrides(groups[group], values, f"{prefix}.{group}")
        params = dataclasses.replace(params, **replaced)
        params.validate(prefix)
        return params

    def with_overrides(self, **groups: Mapping[str, Any]) -> "RedetectParams":
        """A copy with {group: {key: value}} overrides applied (the ablation's switch)."""
        replaced = {group: _with_overrides(getattr(self, group), values, f"redetect.{group}")
                    for group, values in groups.items()}
        params = dataclasses.replace(self, **replaced)
        params.validate()
        return params


def _with_overrides(group: Any, values: Any, prefix: str) -> Any:
    """`group` (a frozen dataclass) with `values` {key: value} applied, types coerced."""
    if not isinstance(values, Mapping):
        raise ValueError(f"{prefix} must be a mapping of keys, got {values!r}")
    known = {f.name for f in dataclasses.fields(group)}
    coerced = {}
    for key, value in values.items():
        if key not in known:
            raise ValueError(f"unknown key {prefix}.{key}; expected one of {', '.join(sorted(known))}")
        coerced[key] = _coerce(f"{prefix}.{key}", value, getattr(group, key))
    return dataclasses.replace(group, **coerced)


def _coerce(name: str, value: Any, default: Any) -> Any:
    """`value` as the type of `default`, or ValueError naming `name`."""
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{name} must be a list of numbers, got {value!r}")
        return tuple(_coerce(name, v, 0.0) for v in value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
        return value
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be a bool, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return int(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _require(prefix: str, key: str, ok: bool, expected: str) -> None:
    if not ok:
        raise ValueError(f"{prefix}.{key} must be {expected}")
