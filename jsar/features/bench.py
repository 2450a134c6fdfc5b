"""Feature-extraction benchmark on one thread: `python -m jsar.features.bench [--frames N] [--json FILE]`.

Times (median over repeats, milliseconds) the per-frame feature work of the JSAR tracker on a real
frame (first frame of a sequence under JSAR_DATA_ROOT when set, else a synthetic 1280x720 frame):
- search patch: sample_patch of the 5x context square -> 200x200 BGR, then extract_features (42 ch);
- size filter: sample_patches of the 13x13 scale x aspect grid -> 32x16 grey, then fhog_batch;
and, in the same run, OpenCV's cv2.resize (INTER_AREA) of the same search region and the numpy
reference implementations, so the numbers can be read as ratios on this (noisy, shared) machine.
Set OMP_NUM_THREADS=1 (the Makefile does) before running; cv2 is limited to one thread here.
"""
from __future__ import annotations

import argparse
import json
import os
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
    x0, y0 = int(round(centre[0] - side / 2)), int(round(centre[1] - side / 2))
    inside = 0 <= x0 and 0 <= y0 and x0 + int(side) <= frame.shape[1] and y0 + int(side) <= frame.shape[0]

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
    region = frame[max(y0, 0):y0 + int(side), max(x0, 0):x0 + int(side)]
    if inside:
        timings["opencv_resize_inter_area_search"] = median_ms(
            lambda: cv2.resize(region, (200, 200), interpolation=cv2.INTER_AREA), repeats)
    timings["search_total"] = timings["search_sample_patch"] + timings["search_extract_features"]
    timings["size_total"] = timings["size_sample_patches_169"] + timings["size_fhog_batch_169"]
    cpu = {
        "search_total": cpu_ms(lambda: extract_features(
            patches.sample_patch(frame, centre, (side, side), (200, 200)), 4, table), repeats),
        "size_total": cpu_ms(lambda: fhog_module.fhog_batch(
            patches.sample_patches(grey, centre, sizes, (32, 16)), 4), repeats),
    }
    if inside:
        cpu["opencv_resize_inter_area_search"] = cpu_ms(
            lambda: cv2.resize(region, (200, 200), interpolation=cv2.INTER_AREA), repeats)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200, help="timed calls per measurement (median reported)")
    parser.add_argument("--data-root", default=os.environ.get("JSAR_DATA_ROOT"), help="sequences root (default: $JSAR_DATA_ROOT)")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be positive")
    result = run(args.repeats, args.data_root)
    print(f"source: {result['source']}  box {result['box_xywh']}  search side {result['search_region_side_px']} px")
    print(f"threads: {result['threads']}  cv2 {result['cv2_threads']}  repeats {result['repeats']}")
    print("wall time, median:")
    for key, value in result["ms"].items():  # type: ignore[union-attr]
        print(f"  {key:36s} {value:8.3f} ms")
    print("process CPU time, median:")
    for key, value in result["cpu_ms"].items():  # type: ignore[union-attr]
        print(f"  {key:36s} {value:8.3f} ms")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
