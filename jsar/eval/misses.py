"""python -m jsar.eval.misses LONGTERM.json [...] [--tracker jsar-re] [--events] [--false] [--by-sequence]

What became of each long-term event in `python -m jsar.eval --longterm --json` results, for one tracker:
re-acquired, or why not (`Outcome`, the first that applies: `EventStates.outcome`), with how far the target came
back from where the loss began and from the box on the event's last frame (target sides sqrt(w*h)): a search
that stays where the target vanished and one that follows the track differ there. Several results (seeds,
kernels) are pooled; `--by-sequence` counts outcomes per sequence. `--false`: the frames the protocol counts as
false re-initialisations, by kind (FALSE_KINDS: `false_frames`), and how many "taken" ones ended a short loss
(the core confident again after a brief drop rather than a search's take).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections import Counter
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np

from jsar.eval import longterm, metrics, report

FALSE_KINDS = ("taken while absent", "moved while lost", "jumped while tracking", "taken wrong")


class Outcome(StrEnum):
    """What became of a long-term event, in the order they are tried (when each applies: EventStates.outcome)."""

    REACQUIRED = "re-acquired"
    BEGAN_OFF_TARGET = "began off target"
    TOOK_DURING_ABSENCE = "took during absence"
    TOOK_WRONG_AFTER = "took wrong after"
    STAYED_LOST = "stayed lost"
    NEVER_LOST = "never lost"
    OTHER = "other"


@dataclass(frozen=True)
class EventStates:
    """What the tracker reported around one long-term event: its states on the absent frames (`during`) and on
    the scoring window's frames after the target came back (`after`), whether its box was on the target on the
    frame before, and whether the protocol counted the event re-acquired."""

    during: tuple[str, ...]
    after: tuple[str, ...]
    on_target_before: bool
    reacquired: bool

    @classmethod
    def of(cls, states: list[str], start: int, stop: int, window: int, on_target_before: bool,
           reacquired: bool) -> EventStates:
        """The event [start, stop) absent of a run's per-frame states; window = the frames after the return in
        which a re-acquisition counts."""
        return cls(tuple(states[start:stop]), tuple(states[stop:min(stop + window, len(states))]),
                   on_target_before, reacquired)

    @property
    def at_return(self) -> str | None:
        """The state on the target's first frame back (None: the run ended before it)."""
        return self.after[0] if self.after else None

    @property
    def took_during_absence(self) -> bool:
        """It reported "recovered" while the target was absent."""
        return "recovered" in self.during

    @property
    def outcome(self) -> Outcome:
        """The first outcome that applies."""
        if self.reacquired:
            return Outcome.REACQUIRED
        if not self.on_target_before:
            return Outcome.BEGAN_OFF_TARGET
        if self.took_during_absence:
            return Outcome.TOOK_DURING_ABSENCE
        if "recovered" in self.after:
            return Outcome.TOOK_WRONG_AFTER
        if self.after and all(s == "lost" for s in self.after):
            return Outcome.STAYED_LOST
        if all(s == "tracking" for s in self.during + self.after):
            return Outcome.NEVER_LOST
        return Outcome.OTHER


@dataclass(frozen=True)
class EventOutcome:
    """One event of one run: frames [start, stop) absent, what the tracker did, and where the target came back
    (distances in target sides from the box before the event, and from the box on the event's last frame)."""

    run: str
    kind: str
    start: int
    stop: int
    outcome: Outcome
    from_loss_sides: float
    from_box_sides: float


def classify_event(boxes: np.ndarray, states: list[str], groundtruth: np.ndarray, start: int, stop: int,
                   on_target_before: bool, reacquired: bool, window: int) -> tuple[Outcome, float, float]:
    """(outcome, from_loss_sides, from_box_sides) of the event [start, stop) absent; boxes and groundtruth
    (N, 4) x, y, w, h px, states per frame ("tracking" / "lost" / "recovered"), window = the frames after the
    return in which a re-acquisition counts. Distances NaN when a box or the returning target is missing."""
    if start < 1 or stop >= len(boxes):
        raise ValueError(f"event [{start}, {stop}) needs a frame before it and one after it in {len(boxes)} frames")
    outcome = EventStates.of(states, start, stop, window, on_target_before, reacquired).outcome
    before = boxes[start - 1]
    side = math.sqrt(before[2] * before[3]) if before[2] > 0 and before[3] > 0 else math.nan
    loss_place, last_place, back = metrics.centres(np.array([before, boxes[stop - 1], groundtruth[stop]]))
    from_loss = float(np.hypot(*(back - loss_place))) / side
    from_box = float(np.hypot(*(back - last_place))) / side
    return outcome, from_loss, from_box


def event_outcomes(result: dict, tracker: str) -> list[EventOutcome]:
    """Every scored event of `tracker` in a long-term result (`python -m jsar.eval --longterm --json`)."""
    window = int(result["criteria"]["window"])
    outcomes = []
    for run, entry in result["sequences"].items():
        if tracker not in entry["trackers"]:
            raise ValueError(f"tracker {tracker!r} not in {run}: {', '.join(entry['trackers'])}")
        scores = entry["trackers"][tracker]
        if "longterm" not in scores or "states" not in scores:
            raise ValueError(f"{run}: not a long-term result with per-frame states (rerun with --longterm --json)")
        boxes = report.boxes_from_json(scores["boxes"])
        groundtruth = report.boxes_from_json(entry["groundtruth"])
        kind = entry.get("kind", "")
        for event in scores["longterm"]["events"]:
            start, stop = event["start"], event["start"] + event["length"]
            outcome, from_loss, from_box = classify_event(boxes, scores["states"], groundtruth, start, stop,
                                                          event["on_target_before"], event["reacquired"], window)
            outcomes.append(EventOutcome(run, event.get("kind", kind), start, stop, outcome, from_loss, from_box))
    return outcomes


@dataclass(frozen=True)
class FalseFrame:
    """One frame a run's long-term score counts as a false re-initialisation: its kind (FALSE_KINDS) and, for
    the "taken" kinds, how many "lost" frames came just before it (0 otherwise)."""

    run: str
    frame: int
    kind: str
    loss_frames: int


def false_frames(boxes: np.ndarray, states: list[str], groundtruth: np.ndarray, spans: list[tuple[int, int]],
                 criteria: longterm.LongTermCriteria) -> list[tuple[int, str, int]]:
    """(frame, kind, loss_frames) of every frame longterm_scores counts as a false re-initialisation for these
    boxes (N, 4) x, y, w, h px, states and ground truth, its absent frames the [start, stop) spans."""
    absent = longterm.spans_mask(spans, len(boxes))
    false_absent, wrong_object = longterm.false_reinit_masks(boxes, states, groundtruth, absent, criteria)
    found, lost_run = [], 0
    for index, state in enumerate(states):
        if false_absent[index]:
            kind = ("taken while absent" if state == "recovered" else
                    "moved while lost" if state == "lost" else "jumped while tracking")
            found.append((index, kind, lost_run if state == "recovered" else 0))
        elif wrong_object[index]:
            found.append((index, "taken wrong", lost_run))
        lost_run = lost_run + 1 if state == "lost" else 0
    return found


def run_false_frames(result: dict, tracker: str) -> list[FalseFrame]:
    """false_frames of every run of `tracker` in a long-term result (`python -m jsar.eval --longterm --json`)."""
    criteria = longterm.LongTermCriteria(**result["criteria"])
    frames = []
    for run, entry in result["sequences"].items():
        scores = entry["trackers"][tracker]
        spans = [(e["start"], e["start"] + e["length"]) for e in scores["longterm"]["events"]]
        found = false_frames(report.boxes_from_json(scores["boxes"]), scores["states"],
                             report.boxes_from_json(entry["groundtruth"]), spans, criteria)
        frames.extend(FalseFrame(run, index, kind, loss) for index, kind, loss in found)
    return frames


def false_lines(frames: list[FalseFrame], absent_frames: int, short_loss: int = 3) -> list[str]:
    """A count per kind of false re-initialisation (of absent_frames), and how many "taken" ones ended a loss of
    at most short_loss frames; then the five runs with the most, each with its count per kind."""
    share = f" ({100.0 * len(frames) / absent_frames:.2f} % of {absent_frames} absent frames)" if absent_frames else ""
    lines = [f"{len(frames)} false re-initialisations{share}: " + _by_kind(Counter(f.kind for f in frames))]
    taken = [f for f in frames if f.kind.startswith("taken")]
    if taken:
        short = sum(f.loss_frames <= short_loss for f in taken)
        lines.append(f"taken ({len(taken)}): {short} ended a loss of at most {short_loss} frames")
    kinds_by_run: dict[str, Counter[str]] = {}
    for f in frames:
        kinds_by_run.setdefault(f.run, Counter())[f.kind] += 1
    if kinds_by_run:
        lines.append("runs with the most:")
    most = sorted(kinds_by_run.items(), key=lambda item: -item[1].total())[:5]  # stable: ties in order seen
    lines.extend(f"  {run:40s} {kinds.total()} ({_by_kind(kinds)})" for run, kinds in most)
    return lines


def _by_kind(counts: Counter[str]) -> str:
    """`kind n, kind n` in FALSE_KINDS order, kinds with no frame left out."""
    return ", ".join(f"{kind} {counts[kind]}" for kind in FALSE_KINDS if counts[kind])


def summary_lines(outcomes: list[EventOutcome], near_sides: float = 1.5) -> list[str]:
    """A count per outcome and, for re-acquired and missed events that began on target, where the target came
    back: the median distances and how many came back within near_sides of the loss place / of the box."""
    counts = Counter(o.outcome for o in outcomes)
    lines = [f"{len(outcomes)} events: " + ", ".join(f"{name} {counts[name]}" for name in Outcome if counts[name])]
    groups = {"re-acquired": [o for o in outcomes if o.outcome == Outcome.REACQUIRED],
              "missed (began on target)": [o for o in outcomes
                                           if o.outcome not in (Outcome.REACQUIRED, Outcome.BEGAN_OFF_TARGET)]}
    for name, group in groups.items():
        if not group:
            continue
        loss = np.array([o.from_loss_sides for o in group])
        box = np.array([o.from_box_sides for o in group])
        lines.append(f"{name} {len(group)}: target came back at median {np.nanmedian(loss):.2f} sides from where "
                     f"the loss began, {np.nanmedian(box):.2f} from the box; within {near_sides:g} sides of the "
                     f"loss place {int(np.sum(loss < near_sides))}, of the box {int(np.sum(box < near_sides))}; "
                     f"nearer the loss place {int(np.sum(loss < box))}")
    return lines


def sequence_lines(outcomes: list[EventOutcome]) -> list[str]:
    """Per sequence (the run's name before "+kind"), its events and the count of each outcome, the sequences
    with the most misses first."""
    by_sequence: dict[str, Counter[Outcome]] = {}
    for o in outcomes:
        by_sequence.setdefault(o.run.split("+")[0], Counter())[o.outcome] += 1
    order = sorted(by_sequence, key=lambda name: (by_sequence[name][Outcome.REACQUIRED] - by_sequence[name].total(),
                                                  name))
    width = max(len(name) for name in order) if order else 0
    return [f"{name:{width}s} {sum(by_sequence[name].values()):4d} events: "
            + ", ".join(f"{outcome} {by_sequence[name][outcome]}" for outcome in Outcome if by_sequence[name][outcome])
            for name in order]


def load_longterm(path: Path) -> dict:
    """A `python -m jsar.eval --longterm --json` result; ValueError naming the file if it is not one."""
    result = json.loads(path.read_text())
    if "criteria" not in result:
        raise ValueError(f"{path}: not a long-term result (no 'criteria'): rerun python -m jsar.eval --longterm --json")
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jsar.eval.misses", description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, nargs="+",
                        help="JSON written by python -m jsar.eval --longterm --json (several: pooled)")
    parser.add_argument("--tracker", default="jsar-re")
    parser.add_argument("--events", action="store_true", help="also one line per event not re-acquired")
    parser.add_argument("--false", action="store_true", dest="false_reinit",
                        help="also the false re-initialisations by kind")
    parser.add_argument("--by-sequence", action="store_true", help="also the outcomes per sequence")
    args = parser.parse_args(argv)
    outcomes: list[EventOutcome] = []
    files: list[str] = []  # the file each outcome comes from ("" with one file)
    frames: list[FalseFrame] = []
    absent = 0
    try:
        for path in args.results:
            result = load_longterm(path)
            prefix = f"{path.name}: " if len(args.results) > 1 else ""
            found = event_outcomes(result, args.tracker)
            outcomes += found
            files += [prefix] * len(found)
            if args.false_reinit:
                frames += [dataclasses.replace(f, run=prefix + f.run) for f in run_false_frames(result, args.tracker)]
                absent += sum(entry["trackers"][args.tracker]["longterm"]["absent_frames"]
                              for entry in result["sequences"].values())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"error: {exc}") from exc
    if args.events:
        for prefix, o in zip(files, outcomes):
            if o.outcome != Outcome.REACQUIRED:
                print(f"{prefix + o.run:40s} [{o.start}, {o.stop}) {o.outcome:20s} came back "
                      f"{o.from_loss_sides:5.2f} sides from the loss place, {o.from_box_sides:5.2f} from the box")
    for line in summary_lines(outcomes):
        print(line)
    if args.by_sequence:
        for line in sequence_lines(outcomes):
            print(line)
    if args.false_reinit:
        for line in false_lines(frames, absent):
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
