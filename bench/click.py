"""A click's initial box against the true box: the square (camera.point_proposal false) and the EdgeBoxes
proposal around the object under the click (the default), on the shared sequences.

    OMP_NUM_THREADS=1 python -m bench.click DATA_ROOT [--frames 10] [--jitter 0.3]

For each sequence: frame 0 and `--frames` frames spread evenly over the frames where the target is
visible, each clicked (TRACK_POINT, radius 0, as QGroundControl's click without a drag) at the true
box's centre, or with --jitter J at a seeded random offset of up to J half-sizes from it (an operator
does not hit the exact middle). Prints the IoU of each method's box with the true box per sequence and
over all clicks, checks that every box contains the clicked point, and the median time per selection.
"""
from __future__ import annotations

import argparse
import math
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from jsar.eval.dataset import Sequence, discover_sequences, load_sequence
from service.config import CameraConfig
from service.mavlink.commands import TrackPoint
from service.selection import Box, contains_point, point_box, proposal_box

METHODS = ("square", "proposal")


@dataclass(frozen=True)
class Click:
    """One click's outcome: sequence, frame, method, IoU with the true box, point inside, seconds."""

    sequence: str
    frame: int
    method: str
    iou: float
    contains: bool
    seconds: float


def iou(a: Box, b: Box) -> float:
    """Intersection over union of two (x, y, w, h) boxes."""
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def clicked_frames(sequence: Sequence, count: int) -> list[int]:
    """Frame 0 (or the first visible one) and `count` frames spread evenly over the visible ones."""
    visible = [i for i in range(len(sequence)) if not math.isnan(sequence.groundtruth[i, 0])]
    if not visible:
        return []
    spread = [visible[round(k * (len(visible) - 1) / max(count - 1, 1))] for k in range(count)]
    return sorted(set([visible[0], *spread]))


def click_point(truth: Box, jitter: float, seed: int) -> tuple[float, float]:
    """The true box's centre, moved by a seeded random offset of up to `jitter` half-sizes."""
    x, y, w, h = truth
    rng = np.random.default_rng(seed)
    angle, radius = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(0.0, jitter)
    return (x + w / 2 + radius * math.cos(angle) * w / 2, y + h / 2 + radius * math.sin(angle) * h / 2)


def select(frame: np.ndarray, point: tuple[float, float], method: str, camera: CameraConfig) -> Box:
    """The service's initial box for a radius-0 click at `point` (pixels) with the given method."""
    height, width = frame.shape[:2]
    selection = TrackPoint(point[0] / width, point[1] / height, 0.0)
    square = point_box(selection, (width, height), camera)
    if method == "square":
        return square
    return proposal_box(frame, selection, square, camera.min_box_px) or square


def run(root: Path, frames: int, jitter: float, camera: CameraConfig = CameraConfig()) -> list[Click]:
    """Every method on every clicked frame of every sequence under root."""
    clicks = []
    for folder in discover_sequences(root):
        sequence = load_sequence(folder)
        for index in clicked_frames(sequence, frames):
            image = sequence.read_frame(index)
            truth = tuple(float(v) for v in sequence.groundtruth[index])
            point = click_point(truth, jitter, seed=index)
            for method in METHODS:
                start = time.perf_counter()
                box = select(image, point, method, camera)
                seconds = time.perf_counter() - start
                clicks.append(Click(sequence.name, index, method, iou(box, truth), contains_point(box, point), seconds))
    return clicks


def summary_rows(clicks: list[Click]) -> list[tuple[str, str, int, float, float, float]]:
    """(sequence or 'all', method, clicks, mean IoU, median IoU, fraction with IoU >= 0.5)."""
    rows = []
    names = sorted({c.sequence for c in clicks}) + ["all"]
    for name in names:
        for method in METHODS:
            values = [c.iou for c in clicks if c.method == method and name in ("all", c.sequence)]
            rows.append((name, method, len(values), statistics.fmean(values), statistics.median(values),
                         sum(v >= 0.5 for v in values) / len(values)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--frames", type=int, default=10, help="clicked frames per sequence (plus frame 0)")
    parser.add_argument("--jitter", type=float, default=0.0, help="click offset from the true centre, in half-sizes")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    clicks = run(args.data_root, args.frames, args.jitter)
    print(f"click at the true centre{f' + up to {args.jitter} half-sizes' if args.jitter else ''}, radius 0; "
          f"IoU with the true box")
    print(f"{'sequence':28s} {'method':9s} {'clicks':>6s} {'mean':>6s} {'median':>6s} {'>=0.5':>6s}")
    for name, method, count, mean, median, good in summary_rows(clicks):
        print(f"{name:28s} {method:9s} {count:6d} {mean:6.3f} {median:6.3f} {good:6.2f}")
    for method in METHODS:
        mine = [c for c in clicks if c.method == method]
        print(f"{method}: {sum(c.contains for c in mine)}/{len(mine)} boxes contain the clicked point; median "
              f"{1e3 * statistics.median(c.seconds for c in mine):.1f} ms per selection (one thread)")
    return 0 if all(c.contains for c in clicks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
