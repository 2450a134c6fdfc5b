"""Tracker speed on real sequences, one thread: lock-step ratio against OpenCV CSRT and per-stage times.

    python -m bench.tracking DATA_ROOT [--trackers jsar,csrt] [--sequences a,b] [--stages SEQ]

Every decoded frame is handed to each tracker in turn, so all trackers see the same machine load;
wall time and thread CPU time of `update` only (decoding excluded) are reported, frame-weighted.
`--stages SEQ` times the stages of "jsar" on one sequence by wrapping the stage functions for the
duration of the run (restored afterwards).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads BLAS: speed is measured on one thread

import argparse
import collections
import contextlib
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np


def _first_box(sequence: Path) -> tuple[float, float, float, float]:
    """The 0-based (x, y, w, h) of the first ground-truth row (the file is 1-based MATLAB)."""
    line = (sequence / "groundtruth_rect.txt").read_text().splitlines()[0]
    x, y, w, h = (float(v) for v in line.replace("\t", ",").replace(" ", ",").split(",") if v)
    return (x - 1.0, y - 1.0, w, h)


def _make(name: str, frame: np.ndarray, box: tuple[float, float, float, float]) -> Any:
    """A tracker initialised on `frame`: OpenCV's CSRT / KCF or a jsar.create name."""
    if name in ("csrt", "kcf"):
        tracker = cv2.TrackerCSRT_create() if name == "csrt" else cv2.TrackerKCF_create()
        tracker.init(frame, tuple(int(round(v)) for v in box))
        return tracker
    import jsar

    tracker = jsar.create(name)
    tracker.init(frame, box)
    return tracker


def lockstep(root: Path, names: list[str], sequences: list[str]) -> dict[str, tuple[float, float]]:
    """{tracker: (wall fps, CPU fps)} frame-weighted over `sequences`; prints per-sequence fps."""
    wall = collections.Counter()
    cpu = collections.Counter()
    frames_total = 0
    for seq in sequences:
        files = sorted((root / seq / "img").glob("*.jpg"))
        first = cv2.imread(str(files[0]))
        trackers = {n: _make(n, first, _first_box(root / seq)) for n in names}
        seq_wall = collections.Counter()
        for path in files[1:]:
            frame = cv2.imread(str(path))
            for name, tracker in trackers.items():
                c0, t0 = time.thread_time(), time.perf_counter()
                tracker.update(frame)
                seq_wall[name] += time.perf_counter() - t0
                cpu[name] += time.thread_time() - c0
        count = len(files) - 1
        frames_total += count
        wall.update(seq_wall)
        print(f"{seq:28s} " + "  ".join(f"{n} {count / seq_wall[n]:6.1f} fps" for n in names), flush=True)
    return {n: (frames_total / wall[n], frames_total / cpu[n]) for n in names}


@contextlib.contextmanager
def _stage_timers(totals: collections.Counter) -> Iterator[None]:
    """Wrap the tracker's stage functions with timers accumulating into `totals` (restored on exit)."""
    from jsar.tracking import jsar_tracker, size_filter, translation

    targets: list[tuple[Any, str, str]] = [
        (jsar_tracker.patches, "sample_patch", "features: translation crop 200x200"),
        (jsar_tracker.translation_features, "extract_features", "features: translation gray+fHOG+colour"),
        (size_filter.SizeFilter, "_features", "features: size grid crops + fHOG"),
        (translation.dcf, "admm_solve", "ADMM (translation filter training)"),
        (translation.TranslationFilter, "sample_spectrum", "FFT: window + rfft2 of the sample"),
        (translation.TranslationFilter, "response", "FFT: response + irfft2"),
        (jsar_tracker.dcf, "subpixel_peak", "Newton sub-cell peak"),
        (size_filter.SizeFilter, "spectrum", "size filter: grid DFT"),
        (size_filter.SizeFilter, "train", "size filter: train"),
        (size_filter.SizeFilter, "response", "size filter: response"),
    ]
    originals = [(owner, attr, getattr(owner, attr)) for owner, attr, _ in targets]

    def timed(function: Callable[..., Any], label: str) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                totals[label] += time.perf_counter() - start
        return wrapper

    try:
        for (owner, attr, label), (_, _, function) in zip(targets, originals):
            setattr(owner, attr, timed(function, label))
        yield
    finally:
        for owner, attr, function in originals:
            setattr(owner, attr, function)


def stages(root: Path, sequence: str, name: str = "jsar") -> None:
    """Print ms per frame per stage of `name` on one sequence."""
    import jsar

    files = sorted((root / sequence / "img").glob("*.jpg"))
    frames = [cv2.imread(str(p)) for p in files]
    totals: collections.Counter = collections.Counter()
    tracker = jsar.create(name)
    tracker.init(frames[0], _first_box(root / sequence))
    with _stage_timers(totals):
        start = time.perf_counter()
        for frame in frames[1:]:
            tracker.update(frame)
        total = time.perf_counter() - start
    count = len(frames) - 1
    print(f"{name} on {sequence}: {1000 * total / count:.2f} ms/frame ({count / total:.1f} fps)")
    for label, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"  {label:42s} {1000 * seconds / count:6.2f} ms")
    print(f"  {'rest (bookkeeping, clamps, phase shift)':42s} {1000 * (total - sum(totals.values())) / count:6.2f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--trackers", default="jsar,csrt")
    parser.add_argument("--sequences", default="")
    parser.add_argument("--stages", metavar="SEQ", default="", help="per-stage times of jsar on SEQ instead")
    args = parser.parse_args(argv)
    if not args.data_root.is_dir():
        parser.error(f"{args.data_root} is not a directory")
    cv2.setNumThreads(1)
    # `python -m` imported numpy (via the jsar package) before the environment above could act:
    # cap the BLAS pools now. Multi-threaded BLAS on a busy machine makes the small matrix
    # products of the size-grid DFT and the ADMM box DFT tens of times slower.
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    if args.stages:
        stages(args.data_root, args.stages)
        return 0
    names = [n for n in args.trackers.split(",") if n]
    sequences = args.sequences.split(",") if args.sequences else sorted(
        p.name for p in args.data_root.iterdir() if (p / "img").is_dir())
    result = lockstep(args.data_root, names, sequences)
    print("frame-weighted: " + "  ".join(f"{n} {w:.1f} fps (CPU {c:.1f})" for n, (w, c) in result.items()))
    if "csrt" in result:
        for n, (w, c) in result.items():
            if n != "csrt":
                print(f"{n} / csrt: wall {w / result['csrt'][0]:.2f}x, CPU {c / result['csrt'][1]:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
