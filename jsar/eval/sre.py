"""Spatial robustness evaluation (OTB's SRE): every sequence run from perturbed initial boxes.

A click is never pixel-exact and one exact start can be luck, so each sequence also runs from the eleven
`SRE_STARTS` around the ground truth's first box (0 exact; 2 px diagonal shifts; 10 % shifts; scales 0.9 and
1.1 about the centre), clipped to the frame and always scored against the unperturbed ground truth. Boxes are
0-based (x, y, w, h) float pixels, top-left origin. `--starts`: STARTS_SYNTAX. The spread over the starts
(`spread`: mean, population std, min, max) is per sequence of a tracker's per-start figures and per set of the
per-start set figures (mean over sequences for AUC / precision, pooled over runs for the long-term rates).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jsar.eval import longterm


@dataclass(frozen=True)
class Start:
    """One initial box rule: shift by (dx, dy) px plus (fx * w, fy * h), then scale w, h about the centre."""

    index: int
    name: str
    shift_px: tuple[float, float] = (0.0, 0.0)
    shift_size: tuple[float, float] = (0.0, 0.0)  # fractions of the box's own w, h
    scale: float = 1.0


SRE_STARTS: tuple[Start, ...] = (
    Start(0, "exact"),
    Start(1, "shift2_+x+y", shift_px=(2.0, 2.0)),
    Start(2, "shift2_+x-y", shift_px=(2.0, -2.0)),
    Start(3, "shift2_-x+y", shift_px=(-2.0, 2.0)),
    Start(4, "shift2_-x-y", shift_px=(-2.0, -2.0)),
    Start(5, "shift10_-x", shift_size=(-0.1, 0.0)),
    Start(6, "shift10_+x", shift_size=(0.1, 0.0)),
    Start(7, "shift10_-y", shift_size=(0.0, -0.1)),
    Start(8, "shift10_+y", shift_size=(0.0, 0.1)),
    Start(9, "scale0.9", scale=0.9),
    Start(10, "scale1.1", scale=1.1),
)
EXACT = SRE_STARTS[0]
ONE_PASS_METRICS = ("auc", "precision")
LONGTERM_METRICS = ("reacquisition_rate", "false_reinit_rate", "absent_reported_lost_rate")
STARTS_SYNTAX = "exact, sre (all 11 starts) or sre:I,J,... (indices 0-10, including 0)"


def parse_starts(text: str) -> tuple[Start, ...]:
    """--starts value -> the chosen starts in index order; ValueError saying what is wrong."""
    spec = text.strip()
    if spec == "exact":
        return (EXACT,)
    if spec == "sre":
        return SRE_STARTS
    if not spec.startswith("sre:"):
        raise ValueError(f"--starts: expected {STARTS_SYNTAX}, got {text!r}")
    fields = [f.strip() for f in spec[4:].split(",")]
    if not all(f.isdigit() for f in fields):
        raise ValueError(f"--starts {text!r}: indices must be integers 0-{len(SRE_STARTS) - 1} separated by commas")
    indices = [int(f) for f in fields]
    bad = [i for i in indices if i >= len(SRE_STARTS)]
    if bad:
        raise ValueError(f"--starts {text!r}: index {bad[0]} out of range 0-{len(SRE_STARTS) - 1}")
    if len(set(indices)) != len(indices):
        raise ValueError(f"--starts {text!r}: an index is given twice")
    if 0 not in indices:
        raise ValueError(f"--starts {text!r} leaves out 0 (exact): the exact start is reported beside the mean")
    return tuple(SRE_STARTS[i] for i in sorted(indices))


def check_starts(starts: tuple[Start, ...]) -> None:
    """ValueError unless `starts` is non-empty, without repeats, and holds the exact start."""
    names = [s.name for s in starts]
    if EXACT not in starts or len(set(names)) != len(names):
        raise ValueError(f"starts must hold 'exact' and no start twice, got {names}")


def perturbed(box: np.ndarray, start: Start) -> np.ndarray:
    """`box` (x, y, w, h px) moved and scaled by `start`'s rule, unclipped."""
    x, y, w, h = (float(v) for v in box)
    cx = x + w / 2.0 + start.shift_px[0] + start.shift_size[0] * w
    cy = y + h / 2.0 + start.shift_px[1] + start.shift_size[1] * h
    sw, sh = w * start.scale, h * start.scale
    return np.array([cx - sw / 2.0, cy - sh / 2.0, sw, sh])


def clipped(box: np.ndarray, width: int, height: int) -> np.ndarray:
    """`box` (x, y, w, h px) intersected with the frame [0, width] x [0, height]; ValueError if nothing is left."""
    x, y, w, h = (float(v) for v in box)
    x0, y0 = max(x, 0.0), max(y, 0.0)
    x1, y1 = min(x + w, float(width)), min(y + h, float(height))
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"box {[x, y, w, h]} lies outside the {width}x{height} frame")
    return np.array([x0, y0, x1 - x0, y1 - y0])


def start_box(box: np.ndarray, start: Start, frame_shape: tuple[int, ...]) -> np.ndarray:
    """The initial box of `start` for ground-truth box `box` on a frame of `frame_shape` (H, W, ...):
    the exact box as it is, a perturbed one clipped to the frame."""
    exact = np.asarray(box, dtype=np.float64)
    if start == EXACT:
        return exact.copy()
    height, width = frame_shape[:2]
    return clipped(perturbed(exact, start), width, height)


def spread(values: list[float | None]) -> dict[str, float | int | None]:
    """Mean, population std (ddof 0), min and max of the finite `values` (None / NaN skipped), and how many."""
    kept = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    if kept.size == 0:
        return {"mean": None, "std": None, "min": None, "max": None, "n": 0}
    return {"mean": float(kept.mean()), "std": float(kept.std()), "min": float(kept.min()),
            "max": float(kept.max()), "n": int(kept.size)}


def aggregate(per_start: dict[str, dict[str, float | None]], metrics: tuple[str, ...]
              ) -> dict[str, dict[str, float | int | None]]:
    """{metric: spread over the starts + "exact": the exact start's value} from {start name: {metric: value}}."""
    return {m: {**spread([row[m] for row in per_start.values()]), "exact": per_start[EXACT.name][m]}
            for m in metrics}


def run_headline(entry: dict[str, object]) -> dict[str, float | None]:
    """One run's figures: AUC and precision, and its long-term rates when it was scored long-term."""
    row: dict[str, float | None] = {"auc": float(entry["auc"]),  # type: ignore[arg-type]
                                    "precision": float(entry["precision"])}  # type: ignore[arg-type]
    if "longterm" in entry:
        rates = longterm.summarise_longterm([entry["longterm"]])  # type: ignore[list-item]
        row.update({m: rates[m] for m in LONGTERM_METRICS})  # type: ignore[misc]
    return row


def set_headline(entries: list[dict[str, object]]) -> dict[str, float | int | None]:
    """A set's figures for one start: mean AUC / precision over its runs and, for long-term runs, the rates
    pooled over them (as jsar.eval's summary does for one start)."""
    row: dict[str, float | int | None] = {
        "auc": float(np.mean([e["auc"] for e in entries])),
        "precision": float(np.mean([e["precision"] for e in entries])),
    }
    if entries and "longterm" in entries[0]:
        pooled = longterm.summarise_longterm([e["longterm"] for e in entries])  # type: ignore[misc]
        row.update({m: pooled[m] for m in LONGTERM_METRICS})
        row["n_events"] = pooled["n_events"]
        row["absent_frames"] = pooled["absent_frames"]
    return row


PER_START_KEYS = ("auc", "precision", "frames_scored", "fps", "seconds", "error", "failed_at", "boxes", "states",
                  "longterm")


def section(starts: tuple[Start, ...], boxes: dict[str, dict[str, np.ndarray]],
            entries: dict[str, dict[str, dict[str, dict[str, object]]]]) -> dict[str, object]:
    """The JSON's "sre" part from boxes {run: {start: initial box}} and entries {run: {start: {tracker:
    jsar.eval entry}}} (run = a sequence, or sequence+kind for --longterm): per run and start the initial box
    and each tracker's figures and per-frame output; per run and tracker, and per tracker over the set, the
    spread over the starts of each figure beside the exact start's."""
    check_starts(starts)
    names = [s.name for s in starts]
    trackers = list(next(iter(entries.values()))[EXACT.name]) if entries else []
    is_longterm = any("longterm" in e for run in entries.values() for e in run[EXACT.name].values())
    metrics = ONE_PASS_METRICS + (LONGTERM_METRICS if is_longterm else ())
    sequences: dict[str, object] = {}
    for run, by_start in entries.items():
        per_start = {s: {"box": boxes[run][s],
                         "trackers": {t: {k: e[k] for k in PER_START_KEYS if k in e} for t, e in by_start[s].items()}}
                     for s in names}
        sequences[run] = {"starts": per_start, "trackers": {
            t: aggregate({s: run_headline(by_start[s][t]) for s in names}, metrics) for t in trackers}}
    summary: dict[str, object] = {}
    for t in trackers:
        per_start_set = {s: set_headline([by_start[s][t] for by_start in entries.values()]) for s in names}
        summary[t] = {"per_start": per_start_set, **aggregate(per_start_set, metrics)}  # type: ignore[arg-type]
    return {"starts": [{"index": s.index, "name": s.name} for s in starts], "metrics": list(metrics),
            "std": "population standard deviation (ddof 0) over the starts",
            "sequences": sequences, "summary": summary}
