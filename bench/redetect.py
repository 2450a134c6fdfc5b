"""Cost of JSAR-Re's re-detection, one thread: `python -m bench.redetect DATA_ROOT [--frames N]`.

`--size-blend` instead measures which re-initialisation size is best: on every sequence, every 10th
frame after 30, re-detection is forced at the tracker's current box (omega 5) on the next frame and,
where the best candidate lands on the target (centre error <= 20 px), the IoU with ground truth of
the re-initialised box is compared for size blends 0 (last confident size) .. 1 (proposal's size).

`--angles 0` times upright-only scoring (RedetectOptions.scoring_angles_deg) against the default.

Per sequence: jsar-re tracks the first N frames normally (timing its confident frames), then on the
next N frames re-detection is forced at the last confident box (proposals + decision-filter scoring,
omega = 5 and omega = 10, no re-initialisation), and the track's verification check (one window) and
a probation challenge (proposals around the track) are timed on the same frames; OpenCV's CSRT runs on the same frames in the same
process for scale. Prints milliseconds per frame (median over frames, pooled over sequences) and
the split between EdgeBoxes proposals and decision-filter scoring.
"""
from __future__ import annotations

import argparse
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from jsar.config import JsarParams  # noqa: E402
from jsar.redetect.jsar_re import JsarReTracker, RedetectOptions, blend_size  # noqa: E402
from jsar.redetect.proposals import generate_proposals  # noqa: E402


def _sequences(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if (p / "img").is_dir() and (p / "groundtruth_rect.txt").is_file())


def _load(folder: Path, count: int) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    paths = sorted((folder / "img").glob("*.jpg"))[:count]
    first = (folder / "groundtruth_rect.txt").read_text().split("\n")[0].replace("\t", ",")
    x, y, w, h = (float(v) for v in first.split(","))
    return [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in paths], (x - 1.0, y - 1.0, w, h)


def _ms(fn) -> float:  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    fn()
    return (time.perf_counter() - start) * 1e3


def _groundtruth(folder: Path) -> np.ndarray:
    rows = [line.replace("\t", ",").split(",") for line in (folder / "groundtruth_rect.txt").read_text().split("\n") if line.strip()]
    gt = np.array([[float(v) for v in row] for row in rows])
    gt[:, :2] -= 1.0  # MATLAB 1-based -> 0-based
    return gt


def _iou(a: tuple[float, ...], b: np.ndarray) -> float:
    iw = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = iw * ih
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def size_blend_study(root: Path, blends: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)) -> None:
    """Print the mean IoU of the re-initialised box per size blend (see the module docstring)."""
    overlaps: dict[float, list[float]] = {b: [] for b in blends}
    forced = 0
    for folder in _sequences(root):
        gt = _groundtruth(folder)
        paths = sorted((folder / "img").glob("*.jpg"))
        tracker = JsarReTracker(JsarParams.jsar_re(), RedetectOptions(size_blend=1.0))
        tracker.init(cv2.imread(str(paths[0]), cv2.IMREAD_COLOR), tuple(gt[0]))
        for index in range(1, len(paths) - 1):
            tracker.update(cv2.imread(str(paths[index]), cv2.IMREAD_COLOR))
            target = gt[index + 1]
            if index < 30 or index % 10 or np.isnan(target).any():
                continue
            last = tracker.core.box
            outcome = tracker.redetect(cv2.imread(str(paths[index + 1]), cv2.IMREAD_COLOR), last, 5.0, 0.0)
            forced += 1
            if outcome.box is None:
                continue
            x, y, w, h = outcome.box  # proposal's own size (blend 1), centred on the decision peak
            cx, cy = x + w / 2, y + h / 2
            if np.hypot(cx - target[0] - target[2] / 2, cy - target[1] - target[3] / 2) > 20:
                continue
            for blend in blends:
                bw, bh = blend_size((w, h), (last[2], last[3]), blend)
                overlaps[blend].append(_iou((cx - bw / 2, cy - bh / 2, bw, bh), target))
    print(f"forced re-detections: {forced}, best candidate on target: {len(overlaps[blends[0]])}")
    for blend in blends:
        print(f"  size_blend {blend:.2f}: re-initialised box IoU mean {np.mean(overlaps[blend]):.3f}, "
              f"median {np.median(overlaps[blend]):.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--frames", type=int, default=20, help="confident frames, then as many re-detection frames")
    parser.add_argument("--size-blend", action="store_true", help="compare re-initialisation sizes instead")
    parser.add_argument("--angles", default=None,
                        help="comma-separated scoring angles in degrees (default: RedetectOptions' own)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.size_blend:
        size_blend_study(args.data_root)
        return
    options = RedetectOptions() if args.angles is None else RedetectOptions(
        scoring_angles_deg=tuple(float(a) for a in args.angles.split(",")))
    print(f"scoring angles (degrees): {options.scoring_angles_deg}")
    timings: dict[str, list[float]] = {k: [] for k in ("confident", "csrt", "redetect5", "proposals5", "scoring5",
                                                       "redetect10", "verify", "challenge")}
    for folder in _sequences(args.data_root):
        frames, box = _load(folder, 2 * args.frames + 1)
        tracker = JsarReTracker(JsarParams.jsar_re(), options)
        tracker.init(frames[0], box)
        csrt = cv2.TrackerCSRT_create()
        csrt.init(frames[0], tuple(int(round(v)) for v in box))
        for frame in frames[1:args.frames + 1]:
            timings["confident"].append(_ms(lambda: tracker.update(frame)))
            timings["csrt"].append(_ms(lambda: csrt.update(frame)))
        last = tracker.core.box
        centre, size = (last[0] + last[2] / 2, last[1] + last[3] / 2), (last[2], last[3])
        for frame in frames[args.frames + 1:]:
            timings["redetect5"].append(_ms(lambda: tracker.redetect(frame, last, 5.0, 0.02)))
            timings["redetect10"].append(_ms(lambda: tracker.redetect(frame, last, 10.0, 0.02)))
            holder: list = []
            timings["proposals5"].append(_ms(lambda: holder.append(generate_proposals(
                frame, centre, size, 5.0, tracker._edgeboxes, tracker._edges))))
            # the track's periodic verification check (every 10th committed frame) and a probation frame's
            # challenge (after re-initialisations, or on a doubtful check)
            timings["verify"].append(_ms(lambda: tracker.score_track(frame)))
            timings["challenge"].append(_ms(lambda: tracker.challenge(frame, float("inf"))))
            boxes = holder[0].boxes
            if len(boxes):
                timings["scoring5"].append(_ms(lambda: tracker.score_proposals(frame, boxes, size)))
        print(f"{folder.name:28s} confident {np.median(timings['confident'][-args.frames:]):6.1f} ms  "
              f"re-detection (omega 5) {np.median(timings['redetect5'][-args.frames:]):6.1f} ms", flush=True)
    print("\nmedian ms per frame over all sequences (one thread):")
    for key, values in timings.items():
        print(f"  {key:12s} {np.median(values):7.1f} ms   (p90 {np.percentile(values, 90):7.1f})")
    print(f"  re-detection frame (omega 5) / confident frame: {np.median(timings['redetect5']) / np.median(timings['confident']):.1f}x")


if __name__ == "__main__":
    main()
