"""Cost of a lost frame of JSAR-Re against a tracking frame, in time, on one thread (or beside the verifier's).

    python -m bench.redetect DATA_ROOT [--frames N] [--windows K] [--rounds R] [--verifier-worker]


Per sequence, jsar-re tracks frames 1..N as it would anywhere (each `update` timed: "tracking"
frames), then on frames N+1..2N the ground-truth box, grown by a quarter of its side, is filled
with the frame's mean colour (the target hidden), so the monitor declares a loss and every such
frame runs the search: the core's locate around the predicted centre, the decision filter on the
core's sample, and `windows_per_frame` lattice windows (SearchParams). Only frames reported "lost"
count as lost frames. Two settings differ from the defaults: the monitor's warm-up is 0 (a loss may
be declared before frame 30), and the acceptance hold-off outlasts the run, so that no candidate is
taken and every hidden frame stays a search frame (holding off skips no work: a lost frame scores
the same windows; taking a candidate would add a commit to that frame and end the search).
`--windows` overrides the per-frame window budget. `--rounds R` runs each sequence R times and keeps each
frame's fastest (the host's noise out of the maxima). `--verifier-worker`: the tracker has a one-thread executor
as the service's `tracker.verifier_thread` gives it (the deferred verifier work, and a lost frame's share).
Prints the median ms per frame of both kinds, per sequence and pooled, their ratio, and the slowest lost frame
against the median tracking frame: time, where bench.instructions counts instructions.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import copy
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import jsar  # noqa: E402
from jsar.eval.dataset import discover_sequences, load_sequence  # noqa: E402
from jsar.redetect.jsar_re import JsarReTracker  # noqa: E402


def _load(folder: Path, count: int) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """The first `count` frames (BGR) of an OTB-layout sequence and its first box (x, y, w, h) px, 0-based."""
    sequence = load_sequence(folder)
    frames = [sequence.read_frame(index) for index in range(min(count, len(sequence)))]
    x, y, w, h = (float(v) for v in sequence.groundtruth[0])
    return frames, (x, y, w, h)


def hide_target(frame: np.ndarray, box: np.ndarray, margin_sides: float = 0.25) -> np.ndarray:
    """A copy of `frame` with box (x, y, w, h) px, grown by margin_sides x sqrt(w*h) on each side,
    filled with the frame's mean colour; the frame itself when the box is NaN (target not visible)."""
    if np.isnan(box).any():
        return frame
    x, y, w, h = (float(v) for v in box)
    margin = margin_sides * float(np.sqrt(w * h))
    height, width = frame.shape[:2]
    x0, y0 = max(int(x - margin), 0), max(int(y - margin), 0)
    x1, y1 = min(int(np.ceil(x + w + margin)), width), min(int(np.ceil(y + h + margin)), height)
    hidden = frame.copy()
    hidden[y0:y1, x0:x1] = frame.reshape(-1, *frame.shape[2:]).mean(axis=0).astype(frame.dtype)
    return hidden


def searching_tracker(windows_per_frame: int | None = None, overrides: dict[str, Any] | None = None) -> JsarReTracker:
    """jsar-re that declares a loss from the first frame on (warm-up 0) and then searches without
    taking any candidate (hold-off 10^9 lost frames); otherwise the defaults, or jsar.create's `overrides`
    of jsar-re (nested dicts; the warm-up and hold-off win)."""
    overrides = copy.deepcopy(overrides or {})
    redetect = overrides.setdefault("redetect", {})
    redetect.setdefault("monitor", {})["warmup_frames"] = 0
    redetect.setdefault("accept", {})["holdoff_frames"] = 10**9
    if windows_per_frame is not None:
        redetect.setdefault("search", {})["windows_per_frame"] = windows_per_frame
    tracker = jsar.create("jsar-re", **overrides)
    assert isinstance(tracker, JsarReTracker)
    return tracker


def _timed(tracker: JsarReTracker, frame: np.ndarray) -> tuple[float, str]:
    """(ms, state) of one `update`."""
    start = time.perf_counter()
    state = tracker.update(frame).state
    return (time.perf_counter() - start) * 1e3, state


def measure(folder: Path, frames: int, windows_per_frame: int | None, rounds: int = 1,
            verifier_worker: bool = False) -> dict[str, list[float]]:
    """ms of the tracking frames among 1..frames and of the lost frames among frames+1..2*frames
    (target hidden), each frame's fastest of `rounds` runs, and the lattice windows scored on each lost frame;
    verifier_worker: the tracker has a one-thread executor (set_verifier_worker)."""
    sequence = load_sequence(folder)
    count = min(2 * frames + 1, len(sequence))
    images = [sequence.read_frame(index) for index in range(count)]
    hidden = {index: hide_target(images[index], sequence.groundtruth[index]) for index in range(frames + 1, count)}
    times: dict[int, list[float]] = {}
    kinds: dict[int, tuple[str, float]] = {}
    for _ in range(rounds):
        tracker = searching_tracker(windows_per_frame)
        with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="verifier") as worker:
            tracker.set_verifier_worker(worker if verifier_worker else None)
            tracker.init(images[0], tuple(float(v) for v in sequence.groundtruth[0]))
            for index in range(1, count):
                visible = index <= frames
                ms, state = _timed(tracker, images[index] if visible else hidden[index])
                times.setdefault(index, []).append(ms)
                if visible and state == "tracking":
                    kinds[index] = ("tracking", 0.0)
                elif not visible and state == "lost":
                    assert tracker.last_step is not None
                    kinds[index] = ("lost", float(tracker.last_step.windows))
    found: dict[str, list[float]] = {"tracking": [], "lost": [], "windows": []}
    for index, (kind, windows) in sorted(kinds.items()):
        found[kind].append(min(times[index]))
        if kind == "lost":
            found["windows"].append(windows)
    return found


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--frames", type=int, default=20,
                        help="tracking frames, then as many frames with the target hidden")
    parser.add_argument("--windows", type=int, default=None,
                        help="lattice windows per lost frame (default: SearchParams.windows_per_frame)")
    parser.add_argument("--rounds", type=int, default=1, help="runs per sequence; each frame's fastest is kept")
    parser.add_argument("--verifier-worker", action="store_true",
                        help="give the tracker a verifier thread, as the service's tracker.verifier_thread")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    cv2.setNumThreads(1)
    pooled: dict[str, list[float]] = {"tracking": [], "lost": [], "windows": []}
    print(f"{'sequence':28s} {'tracking ms':>11s} {'lost ms':>8s} {'ratio':>6s} {'max lost':>9s} {'lost frames':>12s} "
          f"{'windows':>8s}")
    for folder in discover_sequences(args.data_root):
        found = measure(folder, args.frames, args.windows, args.rounds, args.verifier_worker)
        for key, values in found.items():
            pooled[key].extend(values)
        tracking, lost = _median(found["tracking"]), _median(found["lost"])
        slowest = max(found["lost"], default=float("nan"))
        print(f"{folder.name:28s} {tracking:11.1f} {lost:8.1f} {lost / tracking:5.1f}x {slowest / tracking:8.1f}x "
              f"{len(found['lost']):5d} of {args.frames:<4d} {_median(found['windows']):8.0f}", flush=True)
    tracking, lost = _median(pooled["tracking"]), _median(pooled["lost"])
    where = "the tracking thread and a verifier thread" if args.verifier_worker else "one thread"
    print(f"\npooled median ms per frame ({where}): tracking {tracking:.1f} "
          f"({len(pooled['tracking'])} frames), lost {lost:.1f} ({len(pooled['lost'])} frames); "
          f"lost / tracking {lost / tracking:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
