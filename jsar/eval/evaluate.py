"""The evaluation procedures behind `python -m jsar.eval`: one-pass and long-term, returning plain dicts.

Result layout (also what --json writes):
  {"sequences": {seq: {"frames": N, "groundtruth": (N, 4), "trackers": {name: entry}}},
   "summary": {name: {...}}, ["sre": jsar.eval.sre.section(...) when run from several initial boxes]}
where an entry holds precision (at 20 px), auc, the two curves, boxes (N x 4, 0-based x,y,w,h) and,
for trackers run here, fps, seconds, scores and states; published entries have "published": true.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

import jsar
from jsar.api import Tracker
from jsar.eval import dataset, longterm, metrics, sre
from jsar.eval.runner import TrackerRun, run_indexed, track_lockstep

CSRT = "csrt"


def tracker_factories(names: list[str], overrides: dict[str, dict] | None = None
                      ) -> dict[str, Callable[[], Tracker]]:
    """Name -> zero-argument factory via jsar.create; ValueError now if a name is unknown."""
    overrides = overrides or {}
    available = jsar.available()
    unknown = [n for n in names if n not in available]
    if unknown:
        raise ValueError(f"unknown tracker(s) {', '.join(unknown)}; available: {', '.join(available)}")
    return {n: (lambda n=n: jsar.create(n, **overrides.get(n, {}))) for n in names}


def chosen_factories(tracker_names: list[str], factories: dict[str, Callable[[], Tracker]] | None
                     ) -> dict[str, Callable[[], Tracker]]:
    """`factories` when given (its names must be exactly `tracker_names`), else tracker_factories(tracker_names)."""
    if factories is None:
        return tracker_factories(tracker_names)
    if sorted(factories) != sorted(tracker_names):
        raise ValueError(f"factories for {sorted(factories)} but trackers {sorted(tracker_names)}")
    return factories


def truncated(sequence: dataset.Sequence, max_frames: int | None) -> dataset.Sequence:
    """The first `max_frames` frames of `sequence` (all of them when None)."""
    if max_frames is None or max_frames >= len(sequence):
        return sequence
    if max_frames < 2:
        raise ValueError(f"max_frames must be >= 2, got {max_frames}")
    return dataset.Sequence(sequence.name, sequence.frame_paths[:max_frames],
                            sequence.groundtruth[:max_frames])


def frame_time_stats(frame_seconds: np.ndarray) -> dict[str, float]:
    """Per-frame time distribution (ms) of the update() calls (frame 0, init, left out; NaN frames,
    after a crash, skipped): median, 99th percentile (linear interpolation), maximum, p99 / median."""
    updates = np.asarray(frame_seconds, dtype=np.float64)[1:] * 1000.0
    updates = updates[~np.isnan(updates)]
    if updates.size == 0:
        return {"frame_ms_p50": float("nan"), "frame_ms_p99": float("nan"), "frame_ms_max": float("nan"),
                "frame_ms_p99_over_p50": float("nan")}
    p50, p99 = (float(v) for v in np.percentile(updates, [50.0, 99.0]))
    return {"frame_ms_p50": p50, "frame_ms_p99": p99, "frame_ms_max": float(updates.max()),
            "frame_ms_p99_over_p50": p99 / p50 if p50 > 0 else float("nan")}


def run_entry(run: TrackerRun, groundtruth: np.ndarray) -> dict[str, object]:
    """Scores and raw output of one tracker run."""
    entry = metrics.score(run.boxes, groundtruth)
    entry.update(frame_time_stats(run.frame_seconds))
    entry.update({
        "published": False,
        "fps": run.fps,
        "seconds": run.seconds,
        "frames_timed": run.frames_timed,
        "boxes": run.boxes,
        "scores": run.scores,
        "states": run.states,
        "frame_ms": run.frame_seconds * 1000.0,
        "error": run.error,
        "failed_at": run.failed_at,
    })
    return entry


def frame_shape(sequence: dataset.Sequence) -> tuple[int, ...]:
    """(height, width, channels) of the sequence's first frame (to clip perturbed initial boxes)."""
    return sequence.read_frame(0).shape


def start_boxes(first_box: np.ndarray, starts: tuple[sre.Start, ...], sequence: dataset.Sequence
                ) -> dict[str, np.ndarray]:
    """{start name: initial box (x, y, w, h px)}; the first frame is decoded only for perturbed starts."""
    if starts == (sre.EXACT,):
        return {sre.EXACT.name: np.array(first_box, dtype=np.float64)}
    shape = frame_shape(sequence)
    try:
        return {s.name: sre.start_box(first_box, s, shape) for s in starts}
    except ValueError as exc:
        raise ValueError(f"{sequence.name}: {exc}") from exc


def evaluate(sequences: list[dataset.Sequence], tracker_names: list[str],
             published_dir: Path | None = None,
             progress: Callable[[int], None] | None = None,
             max_frames: int | None = None,
             factories: dict[str, Callable[[], Tracker]] | None = None,
             starts: tuple[sre.Start, ...] = (sre.EXACT,), jobs: int = 1) -> dict[str, object]:
    """One-pass evaluation of every tracker (and published result) on every sequence.

    max_frames: score only the first N frames (published files are checked against the full
    sequence, then cut to the same N frames). factories: name -> zero-argument factory for trackers
    that are not jsar.create's defaults (e.g. bench.ablation's variants); names as tracker_names.
    starts: initial boxes (jsar.eval.sre; must hold the exact one): "sequences" and "summary" are the exact
    start's, and with more starts "sre" holds every start's figures and their spread. jobs: (sequence,
    start) runs in that many single-threaded processes (runner.run_indexed).
    """
    factories = chosen_factories(tracker_names, factories)
    sre.check_starts(starts)
    published = dataset.published_trackers(published_dir) if published_dir else []
    clash = set(published) & set(tracker_names)
    if clash:
        raise ValueError(f"published tracker names clash with run trackers: {sorted(clash)}")
    seqs = [truncated(full, max_frames) for full in sequences]
    boxes = {seq.name: start_boxes(seq.groundtruth[0], starts, seq) for seq in seqs}
    units = [(seq, start) for seq in seqs for start in starts]

    def task(index: int, on_frame: Callable[[], None] | None) -> dict[str, dict[str, object]]:
        seq, start = units[index]
        runs = track_lockstep((seq.read_frame(i) for i in range(len(seq))), len(seq),
                              boxes[seq.name][start.name], factories, seq.name, on_frame=on_frame)
        return {name: run_entry(run, seq.groundtruth) for name, run in runs.items()}

    done = run_indexed(task, [len(seq) for seq, _ in units], jobs, progress)
    by_start: dict[str, dict[str, dict[str, dict[str, object]]]] = {seq.name: {} for seq in seqs}
    for (seq, start), entries in zip(units, done):
        by_start[seq.name][start.name] = entries
    per_sequence: dict[str, object] = {}
    for full, seq in zip(sequences, seqs):
        entries: dict[str, object] = dict(by_start[seq.name][sre.EXACT.name])
        for name in published:
            boxes_published = dataset.load_published(published_dir,  # type: ignore[arg-type]
                                                     name, full.name, len(full))
            if boxes_published is None:
                continue
            boxes_published = boxes_published[:len(seq)]
            entry = metrics.score(boxes_published, seq.groundtruth)
            entry.update({"published": True, "boxes": boxes_published})
            entries[name] = entry
        per_sequence[seq.name] = {"frames": len(seq), "groundtruth": seq.groundtruth, "trackers": entries}
    result: dict[str, object] = {"sequences": per_sequence, "summary": summarise(per_sequence)}
    if len(starts) > 1:
        result["sre"] = sre.section(starts, boxes, by_start)
    return result


def summarise(per_sequence: dict[str, object]) -> dict[str, dict[str, object]]:
    """Per tracker: means over its sequences of precision / AUC / fps, frame-weighted fps, ratio vs CSRT."""
    names: list[str] = []
    for seq in per_sequence.values():
        for name in seq["trackers"]:  # type: ignore[index]
            if name not in names:
                names.append(name)
    summary: dict[str, dict[str, object]] = {}
    for name in names:
        entries = [(s["frames"], s["trackers"][name]) for s in per_sequence.values()  # type: ignore[index]
                   if name in s["trackers"]]  # type: ignore[index]
        row: dict[str, object] = {
            "published": bool(entries[0][1]["published"]),
            "sequences": len(entries),
            "precision": float(np.mean([e["precision"] for _, e in entries])),
            "auc": float(np.mean([e["auc"] for _, e in entries])),
            "precision_curve": np.mean([e["precision_curve"] for _, e in entries], axis=0),
            "success_curve": np.mean([e["success_curve"] for _, e in entries], axis=0),
        }
        if not row["published"]:
            frames = sum(e["frames_timed"] for _, e in entries)
            seconds = sum(e["seconds"] for _, e in entries)
            row.update({
                "fps_mean": float(np.mean([e["fps"] for _, e in entries])),
                "fps_frame_weighted": frames / seconds if seconds > 0 else float("nan"),
                "frame_ms_p99_over_p50_worst": float(np.nanmax([e["frame_ms_p99_over_p50"] for _, e in entries])),
                "errors": [f"{e['error'].splitlines()[0]} (frame {e['failed_at']})"
                           for _, e in entries if e["error"]],
            })
        summary[name] = row
    if CSRT in summary:
        csrt_fps = summary[CSRT]["fps_frame_weighted"]
        for row in summary.values():
            if not row["published"]:
                row["fps_ratio_vs_csrt"] = row["fps_frame_weighted"] / csrt_fps  # type: ignore[operator]
        for seq in per_sequence.values():
            trackers = seq["trackers"]  # type: ignore[index]
            if CSRT in trackers:
                for entry in trackers.values():
                    if not entry["published"]:
                        entry["fps_ratio_vs_csrt"] = entry["fps"] / trackers[CSRT]["fps"]
    return summary


def evaluate_longterm(sequences: list[dataset.Sequence], tracker_names: list[str],
                      kinds: list[str], lengths: tuple[int, ...], seed: int,
                      criteria: longterm.LongTermCriteria | None = None,
                      config: longterm.InjectionConfig | None = None,
                      progress: Callable[[int], None] | None = None,
                      max_frames: int | None = None,
                      factories: dict[str, Callable[[], Tracker]] | None = None,
                      starts: tuple[sre.Start, ...] = (sre.EXACT,), jobs: int = 1) -> dict[str, object]:
    """Long-term evaluation: every tracker on every (sequence, event kind) with injected events
    (events placed within the first max_frames frames when given) or, for kind "real", on the
    sequence as it is, scored on its own absent runs (sequences without one are skipped).
    factories, starts, jobs: as in evaluate(); every start of a (sequence, kind) sees the same events."""
    factories = chosen_factories(tracker_names, factories)
    sre.check_starts(starts)
    criteria = criteria or longterm.LongTermCriteria()
    runs_lt: list[longterm.EventSequence] = []
    boxes: dict[str, dict[str, np.ndarray]] = {}
    for seq in (truncated(full, max_frames) for full in sequences):
        for kind in kinds:
            events = longterm.inject_events(seq, kind, lengths, seed, config)
            if kind == "real" and not events.events:
                continue
            runs_lt.append(events)
            # Frame 0 is never inside an injected event (first_start), so the base frame's size is the run's.
            boxes[events.name] = start_boxes(events.groundtruth[0], starts, seq)
    units = [(events, start) for events in runs_lt for start in starts]

    def task(index: int, on_frame: Callable[[], None] | None) -> dict[str, dict[str, object]]:
        events, start = units[index]
        runs = track_lockstep(events.frames(), len(events), boxes[events.name][start.name], factories,
                              events.name, on_frame=on_frame)
        entries: dict[str, dict[str, object]] = {}
        for name, run in runs.items():
            entry = run_entry(run, events.groundtruth)
            lt = longterm.longterm_scores(run.boxes, run.states, events.groundtruth, criteria, events.scored_spans)
            for event in lt["events"]:  # type: ignore[union-attr]
                event["kind"] = events.kind
            entry["longterm"] = lt
            entries[name] = entry
        return entries

    done = run_indexed(task, [len(events) for events, _ in units], jobs, progress)
    by_start: dict[str, dict[str, dict[str, dict[str, object]]]] = {events.name: {} for events in runs_lt}
    for (events, start), entries in zip(units, done):
        by_start[events.name][start.name] = entries
    per_sequence: dict[str, object] = {}
    lt_runs: dict[str, list[dict[str, object]]] = {n: [] for n in tracker_names}
    for events in runs_lt:
        exact = by_start[events.name][sre.EXACT.name]
        for name, entry in exact.items():
            lt_runs[name].append(entry["longterm"])  # type: ignore[arg-type]
        per_sequence[events.name] = {
            "frames": len(events), "groundtruth": events.groundtruth, "base": events.base.name, "kind": events.kind,
            "events": [{"start": e.start, "length": e.length} for e in events.events],
            "dropped_lengths": list(events.dropped_lengths), "trackers": dict(exact),
        }
    summary = summarise(per_sequence)
    for name in tracker_names:
        row = summary[name]
        row["longterm"] = longterm.summarise_longterm(lt_runs[name])
        all_events = [e for lt in lt_runs[name] for e in lt["events"]]  # type: ignore[union-attr]
        row["reacquisition_by_length"] = _rate_by(all_events, "length")
        row["reacquisition_by_kind"] = _rate_by(all_events, "kind")
    result: dict[str, object] = {"sequences": per_sequence, "summary": summary, "seed": seed,
                                 "criteria": criteria.__dict__, "lengths": list(lengths), "kinds": kinds}
    if len(starts) > 1:
        result["sre"] = sre.section(starts, boxes, by_start)
    return result


def _rate_by(events: list[dict[str, object]], key: str) -> dict[str, dict[str, float | int]]:
    """Re-acquisition rate grouped by an event field: {value: {"events": n, "rate": r}}."""
    groups: dict[str, list[bool]] = {}
    for event in events:
        groups.setdefault(str(event[key]), []).append(bool(event["reacquired"]))
    return {k: {"events": len(v), "rate": float(np.mean(v))} for k, v in sorted(groups.items(), key=lambda kv: (len(kv[0]), kv[0]))}
