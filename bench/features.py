"""Feature-extraction benchmark on one thread: `python -m bench.features [--frames N] [--json FILE]`.

Times (median over repeats, milliseconds) the per-frame feature work of the JSAR tracker on a real
frame (first frame of a sequence under JSAR_DATA_ROOT when set, else a synthetic 1280x720 frame):
- search patch: sample_patch of the 5x context square -> 200x200 BGR, then extract_features (42 ch);
- size filter: sample_patches of the 13x13 scale x aspect grid -> 32x16 grey, then fhog_batch;
and, in the same run, OpenCV yardsticks (cv2.resize of a same-size search region, cv2.HOGDescriptor
with 4-px cells on the 200x200 grey patch, a loop of 169 crop + cv2.resize INTER_AREA) and the numpy
reference implementations, so the numbers can be read as ratios on this (noisy, shared) machine.
With --tracker-frames N it also runs the "jsar" tracker over the first N frames of that sequence
under cProfile (process CPU time) and reports how much of its per-frame time the feature
functions take. Set OMP_NUM_THREADS=1 (the Makefile does) before running; cv2 is limited to one
thread here.
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from jsar.features import fhog as fhog_module
from jsar.features import patches
from jsar.features.colour import derived_colour_table
from jsar.features.translation import extract_features

SCALE_STEP = 1.03
ASPECT_STEP = 1.02 ** 2  # the size filter's aspect ratio step as applied to (w, h)
GRID = 13


def median_ms(func: Callable[[], object], repeats: int, clock: Callable[[], float] = time.perf_counter) -> float:
    """Median time of `func` in milliseconds over `repeats` calls (after one warm-up call) on `clock`."""
    func()
    times = []
    for _ in range(repeats):
        start = clock()
        func()
        times.append((clock() - start) * 1e3)
    return statistics.median(times)


def cpu_ms(func: Callable[[], object], repeats: int) -> float:
    """Median process CPU time in ms: less sensitive than wall time to other processes on a shared machine."""
    return median_ms(func, repeats, time.process_time)


def size_grid(width: float, height: float) -> np.ndarray:
    """(169, 2) region sizes (w, h) pixels of the 13 x 13 scale x aspect grid around (width, height)."""
    steps = np.arange(GRID) - GRID // 2
    scale = SCALE_STEP ** steps[:, None]
    aspect = ASPECT_STEP ** steps[None, :]
    return np.stack([(width * scale * aspect).ravel(), (height * scale / aspect).ravel()], axis=1)


def load_frame(data_root: str | None) -> tuple[np.ndarray, tuple[float, float, float, float], str]:
    """A real frame and its ground-truth box (0-based x, y, w, h) if a data root is given, else a synthetic frame."""
    if data_root:
        for seq in sorted(Path(data_root).iterdir()):
            images = sorted((seq / "img").glob("*.jpg"))
            truth = seq / "groundtruth_rect.txt"
            if not images or not truth.is_file():
                continue
            first = truth.read_text().splitlines()[0].replace("\t", ",").replace(" ", ",")
            x, y, w, h = (float(v) for v in first.split(",") if v)
            frame = cv2.imread(str(images[0]), cv2.IMREAD_COLOR)
            if frame is not None and frame.shape[1] >= 960:
                return frame, (x - 1.0, y - 1.0, w, h), f"{seq.name} frame 1"
    rng = np.random.default_rng(0)
    frame = cv2.GaussianBlur(rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8), (0, 0), 2.0)
    return frame, (600.0, 330.0, 60.0, 40.0), "synthetic 1280x720"


def run(repeats: int, data_root: str | None) -> dict[str, object]:
    """All timings as a dict (milliseconds)."""
    cv2.setNumThreads(1)
    frame, (x, y, w, h), source = load_frame(data_root)
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    table = derived_colour_table()
    centre = (x + w / 2, y + h / 2)
    side = 5.0 * np.sqrt(w * h)
    patch = patches.sample_patch(frame, centre, (side, side), (200, 200))
    model_scale = min(1.0, np.sqrt(512.0 / (w * h)))
    sizes = size_grid(w, h)
    small = patches.sample_patches(grey, centre, sizes, (32, 16))
    # OpenCV yardsticks for the same jobs (a region of the same size, moved inside the frame).
    side_px = min(int(round(side)), frame.shape[0], frame.shape[1])
    x0 = int(np.clip(round(centre[0] - side_px / 2), 0, frame.shape[1] - side_px))
    y0 = int(np.clip(round(centre[1] - side_px / 2), 0, frame.shape[0] - side_px))
    region = frame[y0:y0 + side_px, x0:x0 + side_px]
    hog = cv2.HOGDescriptor((200, 200), (8, 8), (4, 4), (4, 4), 9)
    grey_patch = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)

    def opencv_crops_169() -> None:
        for w_n, h_n in sizes:
            wi, hi = max(1, int(round(w_n))), max(1, int(round(h_n)))
            xa = int(np.clip(round(centre[0] - wi / 2), 0, grey.shape[1] - wi))
            ya = int(np.clip(round(centre[1] - hi / 2), 0, grey.shape[0] - hi))
            cv2.resize(grey[ya:ya + hi, xa:xa + wi], (32, 16), interpolation=cv2.INTER_AREA)

    timings: dict[str, float] = {
        "search_sample_patch": median_ms(lambda: patches.sample_patch(frame, centre, (side, side), (200, 200)), repeats),
        "search_extract_features": median_ms(lambda: extract_features(patch, 4, table), repeats),
        "search_fhog_only": median_ms(lambda: fhog_module.fhog(patch, 4), repeats),
        "size_sample_patches_169": median_ms(lambda: patches.sample_patches(grey, centre, sizes, (32, 16)), repeats),
        "size_fhog_batch_169": median_ms(lambda: fhog_module.fhog_batch(small, 4), repeats),
        "reference_numpy_fhog_batch_169": median_ms(lambda: fhog_module.fhog_batch_reference(small, 4), max(3, repeats // 10)),
        "reference_numpy_resample_169": median_ms(
            lambda: patches.resample_regions_reference(grey, centre, sizes, (32, 16)), max(3, repeats // 10)),
    }
    timings["opencv_resize_search"] = median_ms(
        lambda: cv2.resize(region, (200, 200), interpolation=cv2.INTER_AREA if side_px > 200 else cv2.INTER_LINEAR),
        repeats)
    timings["opencv_hog_descriptor_search_grey"] = median_ms(lambda: hog.compute(grey_patch), repeats)
    timings["opencv_crop_resize_loop_169"] = median_ms(opencv_crops_169, repeats)
    timings["search_total"] = timings["search_sample_patch"] + timings["search_extract_features"]
    timings["size_total"] = timings["size_sample_patches_169"] + timings["size_fhog_batch_169"]
    cpu = {
        "search_total": cpu_ms(lambda: extract_features(
            patches.sample_patch(frame, centre, (side, side), (200, 200)), 4, table), repeats),
        "size_total": cpu_ms(lambda: fhog_module.fhog_batch(
            patches.sample_patches(grey, centre, sizes, (32, 16)), 4), repeats),
    }
    cpu["opencv_hog_descriptor_search_grey"] = cpu_ms(lambda: hog.compute(grey_patch), repeats)
    cpu["opencv_crop_resize_loop_169"] = cpu_ms(opencv_crops_169, repeats)
    return {
        "source": source,
        "box_xywh": [x, y, w, h],
        "search_region_side_px": round(float(side), 1),
        "model_scale": round(float(model_scale), 3),
        "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")},
        "cv2_threads": cv2.getNumThreads(),
        "repeats": repeats,
        "ms": {k: round(v, 3) for k, v in timings.items()},
        "cpu_ms": {k: round(v, 3) for k, v in cpu.items()},
    }


def tracker_profile(data_root: str, n_frames: int) -> dict[str, object]:
    """CPU ms per frame of jsar's update and of the feature work inside it, first n_frames of a sequence."""
    import jsar  # the tracker package: imported here so the feature timings above do not need it

    _, box, source = load_frame(data_root)
    seq_dir = Path(data_root) / source.split(" ")[0]
    paths = sorted((seq_dir / "img").glob("*.jpg"))[:n_frames]
    frames = [cv2.imread(str(path), cv2.IMREAD_COLOR) for path in paths]
    tracker = jsar.create("jsar")
    tracker.init(frames[0], box)
    profiler = cProfile.Profile(time.process_time)
    profiler.enable()
    for frame in frames[1:]:
        tracker.update(frame)
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    per_frame = 1e3 / max(1, len(frames) - 1)

    def entry(suffix: str, name: str) -> tuple | None:
        for (filename, _line, func), value in stats.items():
            if func == name and filename.endswith(suffix):
                return value
        return None

    def cumulative(suffix: str, name: str) -> float:
        value = entry(suffix, name)
        return 0.0 if value is None else value[3] * per_frame

    fhog_batch = entry("features/fhog.py", "fhog_batch")
    # fhog_batch called by fhog (inside extract_features) is already counted there.
    size_fhog = 0.0 if fhog_batch is None else sum(
        ct for (filename, _l, func), (_cc, _nc, _tt, ct) in fhog_batch[4].items()
        if not (func == "fhog" and filename.endswith("features/fhog.py"))) * per_frame
    search_sample = cumulative("features/patches.py", "sample_patch")
    all_sampling = cumulative("features/patches.py", "sample_patches")  # sample_patch calls it too
    extract = cumulative("features/translation.py", "extract_features")
    rows = {
        "tracker update, total": cumulative("tracking/jsar_tracker.py", "update"),
        "search patch: sample_patch": search_sample,
        "search patch: extract_features": extract,
        "size filter: sample_patches": all_sampling - search_sample,
        "size filter: fhog_batch": size_fhog,
    }
    rows["features, total"] = all_sampling + extract + size_fhog
    return {"sequence": source.split(" ")[0], "frames": len(frames) - 1,
            "cpu_ms_per_frame": {k: round(v, 3) for k, v in rows.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200, help="timed calls per measurement (median reported)")
    parser.add_argument("--data-root", default=os.environ.get("JSAR_DATA_ROOT"), help="sequences root (default: $JSAR_DATA_ROOT)")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    parser.add_argument("--tracker-frames", type=int, default=0,
                        help="also profile the jsar tracker on this many frames of the data-root sequence")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be positive")
    if args.tracker_frames and not args.data_root:
        parser.error("--tracker-frames needs a data root (--data-root or JSAR_DATA_ROOT)")
    result = run(args.repeats, args.data_root)
    if args.tracker_frames:
        result["tracker_profile"] = tracker_profile(args.data_root, max(2, args.tracker_frames))
    print(f"source: {result['source']}  box {result['box_xywh']}  search side {result['search_region_side_px']} px")
    print(f"threads: {result['threads']}  cv2 {result['cv2_threads']}  repeats {result['repeats']}")
    print("wall time, median:")
    for key, value in result["ms"].items():  # type: ignore[union-attr]
        print(f"  {key:36s} {value:8.3f} ms")
    print("process CPU time, median:")
    for key, value in result["cpu_ms"].items():  # type: ignore[union-attr]
        print(f"  {key:36s} {value:8.3f} ms")
    if "tracker_profile" in result:
        profile = result["tracker_profile"]
        print(f"jsar tracker, {profile['sequence']}, {profile['frames']} frames, cProfile CPU ms per frame "  # type: ignore[index]
              "(profiling overhead included):")
        for key, value in profile["cpu_ms_per_frame"].items():  # type: ignore[index]
            print(f"  {key:42s} {value:8.3f} ms")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
