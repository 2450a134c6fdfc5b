"""A selection's initial box against the true box, on OTB-layout sequences. Clicks: the square
(camera.point_proposal false) and the EdgeBoxes proposal around the object under the click (the
default). Drags: the loose rectangle as dragged (camera.rectangle_fit false) and the box fitted to the
object inside it (the default).

    OMP_NUM_THREADS=1 python -m bench.click DATA_ROOT [--frames 10] [--jitter 0.3]
        [--drag-scale 1.5 2.5] [--drag-offset 0.5] [--seed 0] [--no-drags]

For each sequence: frame 0 and `--frames` frames spread evenly over the frames where the target is
visible, each clicked (TRACK_POINT, radius 0, as QGroundControl's click without a drag) at the true
box's centre, or with --jitter J at a seeded random offset of up to J half-sizes from it (an operator
does not hit the exact middle); and each dragged (TRACK_RECTANGLE): the true box's width and height
each enlarged by a factor drawn uniformly from --drag-scale, the true box placed off the rectangle's
centre by a uniform fraction of up to --drag-offset of the free margin on each axis (it stays inside),
the rectangle clipped to the image; drawn from a generator seeded by (--seed, frame index). Prints the
IoU of each method's box with the true box per sequence and over all selections, the fallbacks (a
click's proposal: none contains the point, the square is used; a drag's fit: the rectangle is kept),
checks that every click box contains the clicked point and every fitted box lies in its rectangle, and
the median time per selection. It does not track from the boxes.
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
from service.selection import Box, contains_point, fitted_rectangle_box, inside_fraction, point_box, proposal_box

CLICK_METHODS = ("square", "proposal")
DRAG_METHODS = ("rectangle", "fitted")
METHODS = CLICK_METHODS + DRAG_METHODS


@dataclass(frozen=True)
class Click:
    """One selection's outcome: sequence, frame, method, IoU with the true box, the box holds the clicked
    point (clicks) or lies in the dragged rectangle (drags), seconds, and whether the method fell back
    (proposal: to the square; fitted: to the rectangle, `reason` says why)."""

    sequence: str
    frame: int
    method: str
    iou: float
    contains: bool
    seconds: float
    fallback: bool = False
    reason: str = ""
    min_side: bool = False  # the box's width or height is camera.min_box_px: a smaller box was grown to it


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


def drag_rectangle(truth: Box, image_size: tuple[int, int], scale: tuple[float, float], offset: float,
                   rng: np.random.Generator) -> Box:
    """A loose rectangle around the true box: width and height each times a factor uniform in `scale`, the
    true box off the rectangle's centre by up to `offset` x the free margin per axis, clipped to the image."""
    x, y, w, h = truth
    sx, sy = rng.uniform(scale[0], scale[1], 2)
    ox, oy = rng.uniform(-offset, offset, 2)
    rw, rh = w * sx, h * sy
    cx, cy = x + w / 2 + ox * (rw - w) / 2, y + h / 2 + oy * (rh - h) / 2
    x0, y0 = max(0.0, cx - rw / 2), max(0.0, cy - rh / 2)
    x1, y1 = min(float(image_size[0]), cx + rw / 2), min(float(image_size[1]), cy + rh / 2)
    return (x0, y0, x1 - x0, y1 - y0)


def select(frame: np.ndarray, point: tuple[float, float], method: str, camera: CameraConfig) -> tuple[Box, bool]:
    """The service's initial box for a radius-0 click at `point` (pixels) with the given method, and whether
    the proposal fell back to the square."""
    height, width = frame.shape[:2]
    selection = TrackPoint(point[0] / width, point[1] / height, 0.0)
    square = point_box(selection, (width, height), camera)
    if method == "square":
        return square, False
    proposal = proposal_box(frame, selection, square, camera.min_box_px)
    return (square, True) if proposal is None else (proposal, False)


def drag(frame: np.ndarray, rectangle: Box, method: str, camera: CameraConfig) -> tuple[Box, str]:
    """The service's initial box for a dragged rectangle (pixels) with the given method, and the fit's
    outcome ("fitted", or why the rectangle was kept; "" for the rectangle method)."""
    if method == "rectangle":
        return rectangle, ""
    box, reason = fitted_rectangle_box(frame, rectangle, camera)
    return (rectangle if box is None else box), reason


def run(root: Path, frames: int, jitter: float, camera: CameraConfig = CameraConfig(), drags: bool = True,
        drag_scale: tuple[float, float] = (1.5, 2.5), drag_offset: float = 0.5, seed: int = 0) -> list[Click]:
    """Every method on every clicked (and dragged) frame of every sequence under root."""
    clicks = []
    for folder in discover_sequences(root):
        sequence = load_sequence(folder)
        for index in clicked_frames(sequence, frames):
            image = sequence.read_frame(index)
            height, width = image.shape[:2]
            truth = tuple(float(v) for v in sequence.groundtruth[index])
            point = click_point(truth, jitter, seed=index)
            for method in CLICK_METHODS:
                start = time.perf_counter()
                box, fallback = select(image, point, method, camera)
                seconds = time.perf_counter() - start
                clicks.append(Click(sequence.name, index, method, iou(box, truth), contains_point(box, point), seconds,
                                    fallback, "no_proposal" if fallback else "",
                                    min(box[2], box[3]) <= camera.min_box_px + 1e-9))
            if not drags:
                continue
            rectangle = drag_rectangle(truth, (width, height), drag_scale, drag_offset,
                                       np.random.default_rng([seed, index]))
            for method in DRAG_METHODS:
                start = time.perf_counter()
                box, reason = drag(image, rectangle, method, camera)
                seconds = time.perf_counter() - start
                clicks.append(Click(sequence.name, index, method, iou(box, truth),
                                    inside_fraction(box, rectangle) > 1 - 1e-9, seconds,
                                    reason not in ("", "fitted"), reason,
                                    min(box[2], box[3]) <= camera.min_box_px + 1e-9))
    return clicks


def summary_rows(clicks: list[Click]) -> list[tuple[str, str, int, float, float, float, int]]:
    """(sequence or 'all', method, selections, mean IoU, median IoU, fraction with IoU >= 0.5, fallbacks)."""
    rows = []
    names = sorted({c.sequence for c in clicks}) + ["all"]
    for name in names:
        for method in METHODS:
            mine = [c for c in clicks if c.method == method and name in ("all", c.sequence)]
            if not mine:
                continue
            values = [c.iou for c in mine]
            rows.append((name, method, len(values), statistics.fmean(values), statistics.median(values),
                         sum(v >= 0.5 for v in values) / len(values), sum(c.fallback for c in mine)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("--frames", type=int, default=10, help="clicked frames per sequence (plus frame 0)")
    parser.add_argument("--jitter", type=float, default=0.0, help="click offset from the true centre, in half-sizes")
    parser.add_argument("--drag-scale", type=float, nargs=2, default=(1.5, 2.5), metavar=("MIN", "MAX"),
                        help="a drag's width and height = the true box's times a factor uniform in [MIN, MAX]")
    parser.add_argument("--drag-offset", type=float, default=0.5,
                        help="the true box's offset from the drag's centre, up to this fraction of the free margin")
    parser.add_argument("--seed", type=int, default=0, help="drags' random generator seed (with the frame index)")
    parser.add_argument("--no-drags", action="store_true", help="clicks only")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    clicks = run(args.data_root, args.frames, args.jitter, drags=not args.no_drags,
                 drag_scale=tuple(args.drag_scale), drag_offset=args.drag_offset, seed=args.seed)
    print(f"click at the true centre{f' + up to {args.jitter} half-sizes' if args.jitter else ''}, radius 0"
          + ("" if args.no_drags else f"; drag {args.drag_scale[0]}-{args.drag_scale[1]}x per side, offset up to "
             f"{args.drag_offset} of the margin, seed {args.seed}") + "; IoU with the true box")
    print(f"{'sequence':28s} {'method':9s} {'count':>6s} {'mean':>6s} {'median':>6s} {'>=0.5':>6s} {'fallbk':>6s}")
    for name, method, count, mean, median, good, fallbacks in summary_rows(clicks):
        print(f"{name:28s} {method:9s} {count:6d} {mean:6.3f} {median:6.3f} {good:6.2f} {fallbacks:6d}")
    for method in METHODS:
        mine = [c for c in clicks if c.method == method]
        if not mine:
            continue
        what = "contain the clicked point" if method in CLICK_METHODS else "lie in the dragged rectangle"
        reasons = sorted({c.reason for c in mine if c.fallback})
        kept = ", ".join(f"{r} {sum(c.reason == r for c in mine)}" for r in reasons)
        print(f"{method}: {sum(c.contains for c in mine)}/{len(mine)} boxes {what}; "
              f"{sum(c.fallback for c in mine)} fallbacks{f' ({kept})' if kept else ''}; "
              f"{sum(c.min_side for c in mine)} with a side of min_box_px; median "
              f"{1e3 * statistics.median(c.seconds for c in mine):.1f} ms per selection (one thread)")
    return 0 if all(c.contains for c in clicks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
