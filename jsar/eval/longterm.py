"""Long-term protocol: target-absent events injected into real sequences, and the metrics on them.

Kinds of event, each hiding the target for K frames before it comes back: "occlusion" (the target region
overwritten by background from beside it, else inpainted: no target pixel stays), "out-of-view" (the frame
translated so the event's boxes lie outside it, a camera that looked away and back) and "real" (nothing
injected: the sequence's own NaN ground-truth runs followed by a visible frame). Ground truth is NaN inside an
event. Injected events are placed by a seeded generator, never overlapping each other or a real absent run, each
followed by visible frames so re-acquisition can be measured; each run is scored on its own kind's events only.
Frames are produced lazily from the original files. The protocol's figures: docs/evaluation.md.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Iterator, Literal

import cv2
import numpy as np

from jsar.eval import metrics
from jsar.eval.dataset import Sequence

EventKind = Literal["occlusion", "out-of-view", "real"]
EVENT_KINDS: tuple[EventKind, ...] = ("occlusion", "out-of-view", "real")
INJECTED_KINDS: tuple[EventKind, ...] = ("occlusion", "out-of-view")
PLACEMENT_TRIES = 100  # draws of an injected placement before giving up on avoiding real absent runs
DEFAULT_LENGTHS: tuple[int, ...] = (5, 15, 40)


@dataclass(frozen=True)
class EventSpan:
    """Frames [start, start + length) of one event (0-based frame indices); target absent there."""

    kind: str
    start: int
    length: int

    @property
    def stop(self) -> int:
        """First frame after the event (the target's reappearance frame)."""
        return self.start + self.length


@dataclass(frozen=True)
class InjectionConfig:
    """Where and how events are placed and drawn (frames; margin as a fraction of box size)."""

    first_start: int = 30  # no event before this frame: the tracker gets to learn the target first
    gap_after: int = 15  # visible frames required after each event (>= the re-acquisition window)
    margin: float = 0.15  # occluder = gt box grown by this fraction of w and h on each side (+2 px)
    margin_px: float = 2.0


@dataclass(frozen=True)
class EventSequence:
    """A real sequence with injected events: frames (lazily), ground truth with NaN in events."""

    base: Sequence
    kind: str
    events: tuple[EventSpan, ...]
    groundtruth: np.ndarray
    dropped_lengths: tuple[int, ...]  # requested lengths that did not fit in this sequence
    seed: int
    config: InjectionConfig = field(default_factory=InjectionConfig)
    # Per-event fill parameters decided at injection time (occluder side or shift), by event index.
    fills: tuple[tuple[float, float], ...] = ()

    @property
    def name(self) -> str:
        """`<sequence>+<kind>` so runs on the same base sequence stay distinguishable."""
        return f"{self.base.name}+{self.kind}"

    def __len__(self) -> int:
        return len(self.base)

    @property
    def scored_spans(self) -> list[tuple[int, int]]:
        """[start, stop) frame spans this run is scored on: its own events (injected or real)."""
        return [(e.start, e.stop) for e in self.events]

    def event_at(self, index: int) -> int | None:
        """Index into `events` of the injected event covering frame `index`, or None (real: None)."""
        if self.kind == "real":
            return None
        for k, span in enumerate(self.events):
            if span.start <= index < span.stop:
                return k
        return None

    def frame(self, index: int) -> np.ndarray:
        """Frame `index` as HxWx3 uint8 BGR with the event applied when inside one."""
        image = self.base.read_frame(index)
        k = self.event_at(index)
        if k is None:
            return image
        if self.kind == "occlusion":
            box = self.base.groundtruth[index]
            if np.any(np.isnan(box)):
                return image  # already absent in the original ground truth
            region = enlarged_region(box, image.shape, self.config.margin, self.config.margin_px)
            return occlude(image, region, self.fills[k])
        return shift_frame(image, self.fills[k])

    def frames(self) -> Iterator[np.ndarray]:
        """All frames in order, decoded and transformed one at a time."""
        for index in range(len(self)):
            yield self.frame(index)


def event_rng(seed: int, sequence_name: str) -> np.random.Generator:
    """Generator seeded by (seed, crc32 of the sequence name): reproducible, different per sequence."""
    return np.random.default_rng([int(seed), zlib.crc32(sequence_name.encode())])


def place_events(n_frames: int, lengths: tuple[int, ...], rng: np.random.Generator,
                 first_start: int, gap_after: int) -> tuple[list[tuple[int, int]], list[int]]:
    """Random non-overlapping (start, length) spans in [first_start, n_frames), each followed by gap_after.

    Lengths that do not fit are dropped longest first and returned as the second value. The order
    of events in time is shuffled; the free frames are split between the gaps uniformly at random.
    """
    if any(length < 1 for length in lengths):
        raise ValueError(f"event lengths must be >= 1 frame, got {lengths}")
    kept = sorted(lengths)
    dropped: list[int] = []
    while kept and first_start + sum(length + gap_after for length in kept) > n_frames:
        dropped.append(kept.pop())  # the longest
    if not kept:
        return [], dropped
    order = list(rng.permutation(len(kept)))
    ordered = [kept[i] for i in order]
    free = n_frames - first_start - sum(length + gap_after for length in ordered)
    # Split `free` slack frames into len+1 parts (before each event and after the last).
    cuts = np.sort(rng.integers(0, free + 1, size=len(ordered)))
    slack = np.diff(np.concatenate([[0], cuts]))
    spans: list[tuple[int, int]] = []
    cursor = first_start
    for length, extra in zip(ordered, slack):
        start = cursor + int(extra)
        spans.append((start, length))
        cursor = start + length + gap_after
    return spans, dropped


def place_clear_of_absent(visible: np.ndarray, lengths: tuple[int, ...], rng: np.random.Generator,
                          first_start: int, gap_after: int) -> tuple[list[tuple[int, int]], list[int]]:
    """place_events over len(visible) frames, drawn again (up to PLACEMENT_TRIES times) until no
    event nor its gap_after frames touches a frame where `visible` (N,) bool is False; when no draw
    fits, the longest length is dropped (reported with the others that did not fit) and the rest
    tried again. The first draw is kept when the sequence has no absent frame."""
    kept = sorted(lengths)
    dropped: list[int] = []
    while kept:
        for _ in range(PLACEMENT_TRIES):
            spans, too_long = place_events(len(visible), tuple(kept), rng, first_start, gap_after)
            if all(visible[start:start + length + gap_after].all() for start, length in spans):
                return spans, dropped + too_long
        dropped.append(kept.pop())
    return [], dropped


def enlarged_region(box: np.ndarray, shape: tuple[int, ...], margin: float,
                    margin_px: float) -> tuple[int, int, int, int]:
    """Gt box (x, y, w, h) grown by margin*w|h + margin_px per side, as integer x0, y0, x1, y1 clipped to the frame."""
    x, y, w, h = (float(v) for v in box)
    dx = margin * w + margin_px
    dy = margin * h + margin_px
    height, width = shape[:2]
    x0 = int(np.clip(np.floor(x - dx), 0, width))
    y0 = int(np.clip(np.floor(y - dy), 0, height))
    x1 = int(np.clip(np.ceil(x + w + dx), 0, width))
    y1 = int(np.clip(np.ceil(y + h + dy), 0, height))
    return x0, y0, x1, y1


def occluder_offset(region: tuple[int, int, int, int], shape: tuple[int, ...]) -> tuple[float, float]:
    """Offset (dx, dy) to a same-size background patch beside `region` fully inside the frame.

    Tries right, left, below, above (offset = region size + 2 px); (0, 0) if none fits, meaning
    "inpaint instead".
    """
    x0, y0, x1, y1 = region
    w, h = x1 - x0, y1 - y0
    height, width = shape[:2]
    for dx, dy in ((w + 2, 0), (-(w + 2), 0), (0, h + 2), (0, -(h + 2))):
        if 0 <= x0 + dx and x1 + dx <= width and 0 <= y0 + dy and y1 + dy <= height:
            return float(dx), float(dy)
    return 0.0, 0.0


def occlude(image: np.ndarray, region: tuple[int, int, int, int],
            offset: tuple[float, float]) -> np.ndarray:
    """Copy of `image` with region x0,y0,x1,y1 replaced by the patch at `offset` (or inpainted if (0, 0))."""
    x0, y0, x1, y1 = region
    out = image.copy()
    if x1 <= x0 or y1 <= y0:
        return out
    dx, dy = int(offset[0]), int(offset[1])
    height, width = image.shape[:2]
    sx0, sy0, sx1, sy1 = x0 + dx, y0 + dy, x1 + dx, y1 + dy
    # The chosen side may not fit on a later frame (the target moved toward the border).
    if (dx, dy) != (0, 0) and 0 <= sx0 and sx1 <= width and 0 <= sy0 and sy1 <= height:
        out[y0:y1, x0:x1] = image[sy0:sy1, sx0:sx1]
        return out
    fitting = occluder_offset(region, image.shape)
    if fitting != (0.0, 0.0):
        return occlude(image, region, fitting)
    mask = np.zeros(image.shape[:2], np.uint8)
    mask[y0:y1, x0:x1] = 255
    out = cv2.inpaint(image, mask, 5, cv2.INPAINT_TELEA)
    return out


def out_of_view_shift(boxes: np.ndarray, shape: tuple[int, ...], margin_px: float = 8.0) -> tuple[float, float]:
    """Smallest axis-aligned integer translation (dx, dy) that moves every box (x,y,w,h rows) out of the frame."""
    visible = boxes[~np.any(np.isnan(boxes), axis=1)]
    if visible.size == 0:
        return 0.0, 0.0
    ux0 = float(visible[:, 0].min())
    uy0 = float(visible[:, 1].min())
    ux1 = float((visible[:, 0] + visible[:, 2]).max())
    uy1 = float((visible[:, 1] + visible[:, 3]).max())
    height, width = shape[:2]
    candidates = [
        (np.ceil(width - ux0 + margin_px), 0.0),  # content moves right: target exits right edge
        (-np.ceil(ux1 + margin_px), 0.0),  # moves left
        (0.0, np.ceil(height - uy0 + margin_px)),  # moves down
        (0.0, -np.ceil(uy1 + margin_px)),  # moves up
    ]
    dx, dy = min(candidates, key=lambda d: abs(d[0]) + abs(d[1]))
    return float(dx), float(dy)


def shift_frame(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """`image` translated by integer (dx, dy) pixels, same size, uncovered band = replicated edge."""
    dx, dy = int(shift[0]), int(shift[1])
    height, width = image.shape[:2]
    # Index maps instead of warpAffine so the replicated edge is the source's own border row/column.
    cols = np.clip(np.arange(width) - dx, 0, width - 1)
    rows = np.clip(np.arange(height) - dy, 0, height - 1)
    return image[rows[:, None], cols[None, :]]


def inject_events(sequence: Sequence, kind: str, lengths: tuple[int, ...] = DEFAULT_LENGTHS,
                  seed: int = 0, config: InjectionConfig | None = None) -> EventSequence:
    """`sequence` with one event of each length of the given kind ("occlusion" or "out-of-view").

    Ground truth becomes NaN inside the events. Lengths that do not fit the sequence (after
    config.first_start, each followed by config.gap_after frames) are listed in `dropped_lengths`.
    """
    if kind not in EVENT_KINDS:
        raise ValueError(f"unknown event kind {kind!r}; expected one of {', '.join(EVENT_KINDS)}")
    config = config or InjectionConfig()
    gt = np.array(sequence.groundtruth, dtype=np.float64)
    if kind == "real":
        real = tuple(EventSpan("real", start, stop - start) for start, stop in absent_spans(gt) if stop < len(gt))
        return EventSequence(sequence, kind, real, gt, (), int(seed), config, ())
    lengths = tuple(int(v) for v in lengths)
    spans, dropped = place_clear_of_absent(metrics.visible_mask(gt), lengths, event_rng(seed, sequence.name),
                                           config.first_start, config.gap_after)
    first = sequence.read_frame(0)
    events: list[EventSpan] = []
    fills: list[tuple[float, float]] = []
    for start, length in spans:
        stop = start + length
        boxes = sequence.groundtruth[start:stop]
        if kind == "occlusion":
            reference = next((b for b in boxes if not np.any(np.isnan(b))), None)
            offset = (0.0, 0.0) if reference is None else occluder_offset(
                enlarged_region(reference, first.shape, config.margin, config.margin_px), first.shape)
            fills.append(offset)
        else:
            fills.append(out_of_view_shift(boxes, first.shape))
        gt[start:stop] = np.nan
        events.append(EventSpan(kind, start, length))
    return EventSequence(sequence, kind, tuple(events), gt, tuple(dropped), int(seed), config,
                         tuple(fills))


# ---------------------------------------------------------------------------------------------
# Long-term metrics


@dataclass(frozen=True)
class LongTermCriteria:
    """How re-acquisition and false re-initialisation are judged (frames, pixels, IoU)."""

    window: int = 15  # re-acquired if on target within this many frames from the reappearance
    min_iou: float = 0.0  # "on target": IoU > min_iou ...
    max_centre_error_px: float = 20.0  # ... or centre error <= this (tiny targets rarely overlap)
    jump_factor: float = 1.0  # a box jump: centre moves > jump_factor * sqrt(w*h) of previous box
    jump_min_px: float = 10.0  # ... and by more than this many pixels


def absent_spans(groundtruth: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs [start, stop) of NaN ground-truth rows (target absent)."""
    absent = ~metrics.visible_mask(groundtruth)
    spans: list[tuple[int, int]] = []
    index = 0
    n = len(absent)
    while index < n:
        if absent[index]:
            start = index
            while index < n and absent[index]:
                index += 1
            spans.append((start, index))
        else:
            index += 1
    return spans


def on_target(predicted: np.ndarray, groundtruth: np.ndarray, criteria: LongTermCriteria) -> np.ndarray:
    """(N,) bool: IoU > min_iou or centre error <= max_centre_error_px (False where gt is absent)."""
    overlaps = metrics.ious(predicted, groundtruth)
    errors = metrics.centre_errors(predicted, groundtruth)
    with np.errstate(invalid="ignore"):
        hit = (overlaps > criteria.min_iou) | (errors <= criteria.max_centre_error_px)
    return hit & metrics.visible_mask(groundtruth)


def box_jumps(predicted: np.ndarray, criteria: LongTermCriteria) -> np.ndarray:
    """(N,) bool: centre moved more than max(jump_factor*sqrt(w*h) of the previous box, jump_min_px)."""
    boxes = np.asarray(predicted, dtype=np.float64)
    jumps = np.zeros(len(boxes), dtype=bool)
    if len(boxes) < 2:
        return jumps
    c = metrics.centres(boxes)
    moved = np.linalg.norm(c[1:] - c[:-1], axis=1)
    prev_size = np.sqrt(np.clip(boxes[:-1, 2] * boxes[:-1, 3], 0.0, None))
    limit = np.maximum(criteria.jump_factor * prev_size, criteria.jump_min_px)
    with np.errstate(invalid="ignore"):
        jumps[1:] = moved > limit
    return jumps


def spans_mask(spans: list[tuple[int, int]], n_frames: int) -> np.ndarray:
    """(n_frames,) bool: True on the frames of the [start, stop) spans."""
    mask = np.zeros(n_frames, dtype=bool)
    for start, stop in spans:
        mask[start:stop] = True
    return mask


def false_reinit_masks(predicted: np.ndarray, states: list[str], groundtruth: np.ndarray, absent: np.ndarray,
                       criteria: LongTermCriteria) -> tuple[np.ndarray, np.ndarray]:
    """(N,) bool masks of the false re-initialisations (see longterm_scores): absent frames where the tracker
    reports "recovered" or its box jumps, and visible frames where it reports "recovered" with IoU 0."""
    recovered_state = np.array([s == "recovered" for s in states], dtype=bool)
    false_absent = absent & (recovered_state | box_jumps(predicted, criteria))
    overlaps = metrics.ious(predicted, groundtruth)
    wrong_object = metrics.visible_mask(groundtruth) & recovered_state & (np.nan_to_num(overlaps, nan=1.0) == 0.0)
    return false_absent, wrong_object


def longterm_scores(predicted: np.ndarray, states: list[str], groundtruth: np.ndarray,
                    criteria: LongTermCriteria | None = None,
                    spans: list[tuple[int, int]] | None = None) -> dict[str, object]:
    """Re-acquisition and false re-initialisation counts for one run (boxes (N,4), states per frame).

    Events are the absent runs of `groundtruth` followed by a visible frame, or the given `spans`
    ([start, stop) frames, each absent in `groundtruth`): then only those frames count as absent
    frames, so a run scores its own events only. An event is re-acquired
    if the box is on target (see on_target) at some frame in [reappear, reappear + window);
    frames_to_recover is that frame minus the reappearance frame; on_target_before says whether the box was
    on target on the frame before the event. A false re-initialisation is an
    absent frame where the tracker reports "recovered" or its box jumps, or a visible frame where it
    reports "recovered" with IoU 0 (re-initialised onto a wrong object). absent_reported_lost counts
    the absent frames on which the tracker said so (state "lost").
    """
    criteria = criteria or LongTermCriteria()
    pred = np.asarray(predicted, dtype=np.float64)
    if len(states) != len(pred):
        raise ValueError(f"{len(states)} states but {len(pred)} boxes")
    hit = on_target(pred, groundtruth, criteria)
    visible = metrics.visible_mask(groundtruth)
    n = len(pred)
    events = []
    if spans is None:
        spans = absent_spans(groundtruth)
        absent = ~visible
    else:
        for start, stop in spans:
            if visible[start:stop].any():
                raise ValueError(f"event span [{start}, {stop}) has visible ground-truth frames")
        absent = spans_mask(spans, n)
    for start, stop in spans:
        if stop >= n:
            continue  # never reappears: no re-acquisition to measure
        window_end = min(stop + criteria.window, n)
        hits = np.flatnonzero(hit[stop:window_end])
        events.append({
            "start": start, "length": stop - start,
            # Whether the box was on target on the frame before the event: an event that begins with the
            # track already off (a one-pass failure, or an earlier event not re-acquired) has no target to
            # re-acquire in the tracker's memory.
            "on_target_before": bool(start > 0 and hit[start - 1]),
            "reacquired": bool(hits.size),
            "frames_to_recover": int(hits[0]) if hits.size else None,
        })
    false_absent, wrong_object = false_reinit_masks(pred, states, groundtruth, absent, criteria)
    recover_frames = [e["frames_to_recover"] for e in events if e["reacquired"]]
    return {
        "events": events,
        "n_events": len(events),
        "n_reacquired": int(sum(e["reacquired"] for e in events)),
        "frames_to_recover": recover_frames,
        "absent_frames": int(absent.sum()),
        "false_reinit_absent": int(false_absent.sum()),
        "false_reinit_wrong_object": int(wrong_object.sum()),
        "absent_reported_lost": int((absent & np.array([s == "lost" for s in states], dtype=bool)).sum()),
    }


def summarise_longterm(per_run: list[dict[str, object]]) -> dict[str, float | int | None]:
    """Pool longterm_scores of several runs: rates over all events and all absent frames."""
    n_events = sum(int(r["n_events"]) for r in per_run)
    n_reacquired = sum(int(r["n_reacquired"]) for r in per_run)
    frames = [f for r in per_run for f in r["frames_to_recover"]]  # type: ignore[union-attr]
    absent = sum(int(r["absent_frames"]) for r in per_run)
    false_absent = sum(int(r["false_reinit_absent"]) for r in per_run)
    wrong = sum(int(r["false_reinit_wrong_object"]) for r in per_run)
    reported = sum(int(r["absent_reported_lost"]) for r in per_run)
    began_on = [e for r in per_run for e in r["events"] if e["on_target_before"]]  # type: ignore[union-attr]
    return {
        "n_events": n_events,
        "reacquisition_rate": n_reacquired / n_events if n_events else None,
        "n_events_on_target_before": len(began_on),
        "reacquisition_rate_on_target_before": (sum(e["reacquired"] for e in began_on) / len(began_on)
                                                if began_on else None),
        "mean_frames_to_recover": float(np.mean(frames)) if frames else None,
        "median_frames_to_recover": float(np.median(frames)) if frames else None,
        "absent_frames": absent,
        "false_reinit_rate": (false_absent + wrong) / absent if absent else None,
        "false_reinit_absent": false_absent,
        "false_reinit_wrong_object": wrong,
        "absent_reported_lost_rate": reported / absent if absent else None,
    }
