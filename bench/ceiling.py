"""How many long-term events a perfect search could re-acquire with JSAR-Re's decision filter, one thread:

    python -m bench.ceiling DATA_ROOT --seed N [--search tracker|oracle|oracle+lattice] [--json F] [--events]
        [--sequences a,b] [--kinds occlusion,out-of-view,real]

The long-term protocol (jsar.eval.longterm: the injected events of the seed and the sequences' own absent
runs) with jsar-re at its defaults. On each of the first `window` frames after a target comes back (the
frames on which the protocol asks for re-acquisition), the decision filter, as it is on that frame, also
scores one window centred on the ground truth: an oracle's window, which the tracker never sees. The
tracker runs exactly as in `python -m jsar.eval --longterm` (the probe only reads its state), so its own
re-acquisitions are those of the long-term table.

The oracle's window "recognises" the target on a frame when, as a lattice candidate there would need:
its peak lies within one target side of the ground-truth centre, scores at least the bar (the decayed bar
of the loss, params.AcceptParams, counted from the tracker's loss or else from the event's start) and
passes the colour check (params.ColourParams.min_match). An event is within the decision filter's reach
when the tracker re-acquired it or the oracle's window recognised the target on confirm_frames + 1
consecutive frames inside the window: the most a search could re-acquire (perfect coverage, no
look-alike ever taken) without another appearance model or a lower bar. Windows are scored at the
tracker's own target side (the last confident size, as the search's) and, separately, at the ground
truth's side (a perfect size too).

That probe counts events on the tracker's own run: its misses cascade (an event missed leaves the next
one beginning off the target). `--search` runs another tracker instead (OracleSearchTracker): "oracle"
gives the lost search only windows centred on the ground truth, and counts the decision filter's score on
the core's own sample only within a side of it, so nothing but the target can end a loss (the motion
gate, hold-off, confirmation, bar and colour check still apply): a perfect search with this decision
filter, cascades included. "oracle+lattice" adds those windows to the tracker's own (perfect coverage,
look-alikes still in reach).

Per seed: events, re-acquired, within reach at the tracker's side and at the ground truth's, each
also for the events that began with the box on the target, and the protocol's false
re-initialisations; then the misses by reason (miss_breakdown); a line per event with --events, and with
--json per event why the oracle's window failed (frames per first failed test: place, bar, colour) and
what became of it (jsar.eval.misses' Outcome).

    python -m bench.ceiling --from-json F [F ...]

prints the misses by reason of saved --json runs, pooled (several seeds).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Mapping
from enum import StrEnum
from pathlib import Path
from typing import Any

from jsar.eval.runner import cap_loaded_pools, limit_threads_env

limit_threads_env()  # before the trackers' modules are imported below

import numpy as np  # noqa: E402

import jsar  # noqa: E402
from jsar.eval import dataset, longterm  # noqa: E402
from jsar.eval.misses import EventStates  # noqa: E402
from jsar.redetect.jsar_re import JsarReTracker, Phase  # noqa: E402
from jsar.redetect.search import LossSearch, decayed_bar  # noqa: E402

SIZES = ("tracker", "groundtruth")  # the side the oracle's window is scored at
FALSE_KEYS = ("false_reinit_absent", "false_reinit_wrong_object", "absent_frames")  # longterm_scores' counts
SEARCHES = ("tracker", "oracle", "oracle+lattice")  # --search: what the lost tracker's search scores
SEARCH_PLACES = ("outside gate", "outside lattice", "inside lattice", "first ring")  # search_reach's answers


class OracleSearchTracker(JsarReTracker):
    """jsar-re whose lost search is given the ground truth (a diagnostic, never a tracker: it overrides
    JsarReTracker's private search hooks). `groundtruth_box` (x, y, w, h px; NaN: absent) must be set
    before each update. "oracle": the search scores only windows centred on the target (upright and at
    the search's turned angles), and the decision filter's score on the core's own sample counts only
    where the target is (within a side), so no look-alike, occluder or background can end a loss;
    "oracle+lattice": the target's windows are added to the tracker's own (perfect coverage, look-alikes
    still there)."""

    def __init__(self, search: str) -> None:
        super().__init__()
        self.oracle = search
        self.groundtruth_box = np.full(4, np.nan)

    def _target_centre(self) -> tuple[float, float] | None:
        box = self.groundtruth_box
        return None if np.any(np.isnan(box)) else (box[0] + box[2] / 2.0, box[1] + box[3] / 2.0)

    def _score_core_sample(self, loc):  # type: ignore[no-untyped-def]
        own = super()._score_core_sample(loc)
        if self.oracle != "oracle" or self.phase is not Phase.LOST or self.loss is None:
            return own
        centre = self._target_centre()
        if centre is None or own.distance_sides(centre, self.loss.side_px) > 1.0:
            return dataclasses.replace(own, score=0.0)
        return own

    def _candidates(self, frame, search, own, worker_busy=0.0):  # type: ignore[no-untyped-def]
        found = super()._candidates(frame, search, own, worker_busy) if self.oracle == "oracle+lattice" else [own]
        centre = self._target_centre()
        if centre is None:
            return found
        assert self.decision_filter is not None
        angles = np.array([0.0, *self.redetect.search.turned_angles_deg])
        windows = self.decision_filter.score_windows(self.core.prepare(frame), self.core.feature_colour_table,
                                            np.repeat([centre], len(angles), axis=0), search.side_px, angles)
        factor = self.redetect.search.turned_score_factor
        return found + [c if c.angle_deg == 0 else dataclasses.replace(c, score=c.score * factor) for c in windows]


@dataclasses.dataclass(frozen=True)
class OracleLook:
    """The oracle's window on one frame: the decision filter's peak (raw) and the bar it must reach, the
    colour check's relative match (inf: no check) and its minimum, and how far the peak lies from the
    ground truth's centre (target sides)."""

    score: float
    bar: float
    colour: float
    colour_min: float
    off_sides: float

    def failed_test(self) -> str | None:
        """The first of the candidate's tests this look fails ("place", "bar", "colour"), None if it passes."""
        if self.off_sides > 1.0:
            return "place"
        if self.score < self.bar:
            return "bar"
        if self.colour < self.colour_min:
            return "colour"
        return None


def oracle_look(tracker: JsarReTracker, frame: np.ndarray, gt_box: np.ndarray, frames_since: int,
                side_px: float) -> OracleLook:
    """A decision-filter window of target side side_px centred on gt_box (x, y, w, h px), judged by the tests
    a lattice candidate must pass on this frame (peak within a side of the ground truth's centre, the bar
    after `frames_since` lost frames, the colour check); reads the tracker's state only."""
    memory, core = tracker.decision_filter, tracker.core
    assert memory is not None
    centre = (gt_box[0] + gt_box[2] / 2.0, gt_box[1] + gt_box[3] / 2.0)
    found = memory.score_windows(core.prepare(frame), core.feature_colour_table, np.array([centre]), side_px)[0]
    accept, zeta_s = tracker.redetect.accept, tracker.redetect.monitor.reliable_peak
    bar = decayed_bar(memory.reference, max(frames_since - 1, 0), accept, zeta_s)
    minimum = tracker.redetect.colour.min_match
    colour = math.inf
    if minimum > 0:
        w, h = (tracker.core_at_loss if tracker.core_at_loss is not None else core).size_wh
        colour = tracker.colour.relative_match(frame, (found.x - w / 2.0, found.y - h / 2.0, w, h))
    return OracleLook(found.score, bar, colour, minimum, found.distance_sides(centre, side_px))


def search_reach(search: LossSearch, gt_box: np.ndarray) -> str:
    """Where the target (gt_box x, y, w, h px) lies for the lost search on this frame: beyond its motion
    gate, inside the gate but beyond the lattice's square (search.py), inside both, or among the windows
    of the centre and the lattice's first ring (within 1.5 strides of the search's centre, Chebyshev)."""
    centre = (gt_box[0] + gt_box[2] / 2.0, gt_box[1] + gt_box[3] / 2.0)
    dx, dy = ((centre[k] - search.anchor_xy[k]) / search.side_px for k in (0, 1))
    if math.hypot(dx, dy) > search.reach_sides:
        return "outside gate"
    if max(abs(dx), abs(dy)) > (search.area_sides() + search.lattice.stride_sides) / 2.0:
        return "outside lattice"
    return "inside lattice" if max(abs(dx), abs(dy)) > 1.5 * search.lattice.stride_sides else "first ring"


def oracle_recognises(tracker: JsarReTracker, frame: np.ndarray, gt_box: np.ndarray, frames_since: int,
                      side_px: float) -> bool:
    """Whether oracle_look's window passes every test a lattice candidate must pass."""
    return oracle_look(tracker, frame, gt_box, frames_since, side_px).failed_test() is None


def run_sequence(events: longterm.EventSequence, window: int, needed: int, search: str = "tracker"
                 ) -> dict[str, object]:
    """jsar-re (its search as `search` says: SEARCHES) over one event sequence with the oracle's window on
    each event's first `window` visible frames; the protocol's scores and, per event, whether it lies
    within reach (per side choice)."""
    tracker = jsar.create("jsar-re") if search == "tracker" else OracleSearchTracker(search)
    assert isinstance(tracker, JsarReTracker)
    n = len(events)
    boxes, states = np.full((n, 4), np.nan), ["absent"] * n
    gt = events.groundtruth
    recognised = {size: np.zeros(n, dtype=bool) for size in SIZES}
    looks: dict[int, OracleLook] = {}  # frame -> the oracle's look at the tracker's side
    where: dict[int, str] = {}  # frame -> where the target lay for the lost search (search_reach)
    probe_frames = {i: e for e in events.events for i in range(e.stop, min(e.stop + window, n))}
    loss_start: int | None = None
    for index, frame in enumerate(events.frames()):
        if index == 0:
            tracker.init(frame, tuple(float(v) for v in gt[0]))
            boxes[0], states[0] = gt[0], "tracking"
            continue
        if isinstance(tracker, OracleSearchTracker):
            tracker.groundtruth_box = gt[index]
        result = tracker.update(frame)
        boxes[index], states[index] = result.box, result.state
        if result.state == "lost" and loss_start is None:
            loss_start = index
        elif result.state != "lost":
            loss_start = None
        event = probe_frames.get(index)
        if event is None or np.any(np.isnan(gt[index])):
            continue
        since = index - (loss_start if loss_start is not None else event.start) + 1
        tracker_side = tracker.loss.side_px if tracker.loss is not None else math.sqrt(
            tracker.box[2] * tracker.box[3])
        sides = {"tracker": tracker_side, "groundtruth": math.sqrt(gt[index][2] * gt[index][3])}
        for size in SIZES:
            look = oracle_look(tracker, frame, gt[index], since, sides[size])
            recognised[size][index] = look.failed_test() is None
            if size == "tracker":
                looks[index] = look
        if tracker.loss is not None:
            where[index] = search_reach(tracker.loss, gt[index])
    scores = longterm.longterm_scores(boxes, states, gt, longterm.LongTermCriteria(window=window),
                                      events.scored_spans)
    for entry in scores["events"]:  # type: ignore[union-attr]
        stop = entry["start"] + entry["length"]
        for size in SIZES:
            hits = recognised[size][stop:stop + window].astype(int)
            run = np.convolve(hits, np.ones(needed, dtype=int), mode="valid") if len(hits) >= needed else []
            entry[f"reach_{size}"] = bool(entry["reacquired"] or np.any(np.asarray(run) >= needed))
            entry[f"recognised_frames_{size}"] = int(hits.sum())
        entry["sequence"], entry["kind"] = events.name, events.kind
        # Why the oracle's window (tracker's side) failed on the event's frames: frames per first failed test,
        # and the best score over the bar.
        seen = [looks[i] for i in range(stop, min(stop + window, n)) if i in looks]  # the tracker's side
        entry["failed_tests"] = {test: sum(look.failed_test() == test for look in seen)
                                 for test in ("place", "bar", "colour")}
        returned = range(stop, min(stop + window, n))
        entry["target_for_search"] = {place: sum(where.get(i) == place for i in returned) for place in SEARCH_PLACES}
        entry["best_score_over_bar"] = max((look.score / look.bar for look in seen), default=None)
        # What the tracker was doing when the target came back: still searching ("lost"), or tracking
        # something it took during the event (a "recovered" frame there) or never let go of.
        reported = EventStates.of(states, entry["start"], stop, window, bool(entry["on_target_before"]),
                                  bool(entry["reacquired"]))
        entry["outcome"] = str(reported.outcome)
        entry["state_at_return"] = reported.at_return
        entry["took_during_event"] = reported.took_during_absence
    return scores


def summary(entries: list[dict[str, object]]) -> dict[str, int]:
    """Counts over events: all, re-acquired, within reach per side choice; the same for began-on-target."""
    out: dict[str, int] = {}
    for prefix, chosen in (("", entries), ("on_target_", [e for e in entries if e["on_target_before"]])):
        out[f"{prefix}events"] = len(chosen)
        out[f"{prefix}reacquired"] = sum(bool(e["reacquired"]) for e in chosen)
        for size in SIZES:
            out[f"{prefix}reach_{size}"] = sum(bool(e[f"reach_{size}"]) for e in chosen)
    return out


class MissReason(StrEnum):
    """Why a missed event was missed, the first that holds (miss_reason)."""

    TRACKING = "tracking"  # not lost when the target came back: following something else (EventStates.at_return)
    BAR = "bar"  # the oracle's window stayed under the bar on every frame
    COLOUR = "colour"  # it passed place and bar wherever it was looked at, and the colour check refused it there
    OTHER = "other"


@dataclasses.dataclass(frozen=True)
class ProbedEvent:
    """What run_sequence found of one event (its JSON entry, typed): the tracker's reading (jsar.eval.misses'
    EventStates), whether within reach at the tracker's side, and the oracle's window's tests."""

    reacquired: bool
    reach_tracker: bool
    state_at_return: str | None
    took_during_event: bool
    recognised_frames_tracker: int
    failed_tests: dict[str, int]  # frames per first failed test: place, bar, colour
    target_for_search: dict[str, int]  # returned frames per SEARCH_PLACES
    best_score_over_bar: float | None

    @classmethod
    def from_json(cls, entry: Mapping[str, Any]) -> ProbedEvent:
        """The fields of one of run_sequence's event entries (or a saved --json's)."""
        return cls(**{f.name: entry[f.name] for f in dataclasses.fields(cls)})


def miss_reason(event: ProbedEvent) -> MissReason:
    """Why a missed event was missed (MissReason: the first that holds)."""
    if event.state_at_return != "lost":
        return MissReason.TRACKING
    if event.best_score_over_bar is not None and event.best_score_over_bar < 1.0:
        return MissReason.BAR
    tests = event.failed_tests
    if event.recognised_frames_tracker == 0 and tests["colour"] > 0 and tests["place"] == tests["bar"] == 0:
        return MissReason.COLOUR
    return MissReason.OTHER


def lay_most(event: ProbedEvent) -> str:
    """Where the target lay for the lost search on most of the event's returned frames (ties: the farther)."""
    return max(SEARCH_PLACES, key=lambda place: event.target_for_search[place])


def miss_breakdown(events: list[ProbedEvent]) -> str:
    """The events not re-acquired, by miss_reason (for "bar": the best frame's score over the bar, median and
    quartiles) and, for those still lost at the return, by lay_most with how many were within reach."""
    missed = [e for e in events if not e.reacquired]
    reasons = [miss_reason(e) for e in missed]
    tracking = [e for e, r in zip(missed, reasons) if r == MissReason.TRACKING]
    taken = sum(e.took_during_event for e in tracking)
    best = [float(e.best_score_over_bar) for e, r in zip(missed, reasons)
            if r == MissReason.BAR and e.best_score_over_bar is not None]
    quartiles = (" (best frame over the bar: median {1:.2f}, quartiles {0:.2f}-{2:.2f})".format(
        *np.percentile(best, [25, 50, 75])) if best else "")
    lost = [e for e in missed if e.state_at_return == "lost"]
    where = [(lay_most(e), e.reach_tracker) for e in lost]
    places = ", ".join(f"{place} {sum(p == place for p, _ in where)} "
                       f"({sum(p == place and reach for p, reach in where)} within reach)"
                       for place in reversed(SEARCH_PLACES))
    return (f"missed {len(missed)}: tracking something else at the return {len(tracking)} (taken during the "
            f"event {taken}); under the bar on every frame {reasons.count(MissReason.BAR)}{quartiles}; refused by "
            f"the colour check {reasons.count(MissReason.COLOUR)}; other {reasons.count(MissReason.OTHER)}. Lost at "
            f"the return {len(lost)}, the target on most frames: {places}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data_root", type=Path, nargs="?")
    parser.add_argument("--from-json", type=Path, nargs="+", default=None,
                        help="print the misses by reason of saved --json runs (pooled) instead of running")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sequences", default="", help="comma-separated sequence names (default: all)")
    parser.add_argument("--kinds", default=",".join(longterm.EVENT_KINDS))
    parser.add_argument("--search", choices=SEARCHES, default="tracker",
                        help="tracker: jsar-re as it is; oracle: its search given only the target's windows; "
                             "oracle+lattice: the target's windows added to its own")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--events", action="store_true", help="a line per event")
    args = parser.parse_args(argv)
    if args.from_json is not None:
        pooled: list[dict[str, object]] = []
        for path in args.from_json:
            events = json.loads(path.read_text())["events"]
            missing = {"failed_tests", "target_for_search", "best_score_over_bar"} - set(events[0] if events else {})
            if missing:
                parser.error(f"--from-json: {path} has no {', '.join(sorted(missing))} "
                             "(written by an older bench.ceiling)")
            pooled.extend(events)
        print(miss_breakdown([ProbedEvent.from_json(e) for e in pooled]))
        return 0
    if args.data_root is None:
        parser.error("data_root is required (or --from-json)")
    cap_loaded_pools()
    folders = dataset.discover_sequences(args.data_root)
    wanted = {s for s in args.sequences.split(",") if s}
    unknown = wanted - {f.name for f in folders}
    if unknown:
        parser.error(f"--sequences: not under {args.data_root}: {', '.join(sorted(unknown))}")
    kinds = [k for k in args.kinds.split(",") if k]
    for kind in kinds:
        if kind not in longterm.EVENT_KINDS:
            parser.error(f"--kinds: unknown kind {kind!r}; expected some of {', '.join(longterm.EVENT_KINDS)}")
    window = longterm.LongTermCriteria().window
    needed = jsar.create("jsar-re").redetect.accept.confirm_frames + 1  # type: ignore[attr-defined]
    entries: list[dict[str, object]] = []
    false = dict.fromkeys(FALSE_KEYS, 0)
    for folder in folders:
        if wanted and folder.name not in wanted:
            continue
        sequence = dataset.load_sequence(folder)
        for kind in kinds:
            events = longterm.inject_events(sequence, kind, longterm.DEFAULT_LENGTHS, args.seed)
            if not events.events:
                continue
            scores = run_sequence(events, window, needed, args.search)
            entries.extend(scores["events"])  # type: ignore[arg-type]
            for key in FALSE_KEYS:
                false[key] += int(scores[key])  # type: ignore[call-overload]
    counts = summary(entries) | false
    if args.events:
        for e in entries:
            print(f"{e['sequence']:40s} start {e['start']:4d} len {e['length']:3d} on-target-before "
                  f"{int(bool(e['on_target_before']))} at-return {e['state_at_return']} took-during "
                  f"{int(bool(e['took_during_event']))} reacquired {int(bool(e['reacquired']))} "
                  f"reach tracker-side {int(bool(e['reach_tracker']))} ({e['recognised_frames_tracker']} frames) "
                  f"gt-side {int(bool(e['reach_groundtruth']))} ({e['recognised_frames_groundtruth']} frames)")
    print(f"seed {args.seed}, search {args.search}: {counts['events']} events, re-acquired {counts['reacquired']}, "
          f"within reach {counts['reach_tracker']} (tracker's side) / {counts['reach_groundtruth']} "
          f"(ground truth's side); "
          f"began on target {counts['on_target_events']}: re-acquired {counts['on_target_reacquired']}, within reach "
          f"{counts['on_target_reach_tracker']} / {counts['on_target_reach_groundtruth']}; false re-initialisations "
          f"{counts['false_reinit_absent']} + {counts['false_reinit_wrong_object']} of {counts['absent_frames']} "
          f"absent frames")
    print(miss_breakdown([ProbedEvent.from_json(e) for e in entries]))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"seed": args.seed, "search": args.search, "summary": counts,
                                         "events": entries}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
