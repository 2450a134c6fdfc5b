"""python -m jsar.eval.compare RESULT.json SEQUENCE A B [--every N] [--min-iou 0.5]

Frame-by-frame comparison of two trackers' boxes from a `python -m jsar.eval --json` result
(run trackers or --published ones, e.g. jsar vs JSAR-reference): where they part, and who is right.
Prints per frame IoU with the ground truth for A and B, IoU(A, B) and both boxes (0-based x,y,w,h px).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from jsar.eval import metrics, report


def divergence(boxes_a: np.ndarray, boxes_b: np.ndarray, groundtruth: np.ndarray,
               min_iou: float = 0.5) -> dict[str, object]:
    """IoU series and the first frame where IoU(A, B) < min_iou, with per-frame winner counts."""
    iou_a = metrics.ious(boxes_a, groundtruth)
    iou_b = metrics.ious(boxes_b, groundtruth)
    mutual = metrics.ious(boxes_a, boxes_b)  # B as the "reference" box; NaN if B is NaN
    apart = np.flatnonzero(np.nan_to_num(mutual, nan=0.0) < min_iou)
    scored = ~np.isnan(iou_a)
    return {
        "iou_a": iou_a, "iou_b": iou_b, "iou_ab": mutual,
        "first_apart": int(apart[0]) if apart.size else None,
        "frames_apart": int(apart.size),
        "a_better": int(np.count_nonzero(iou_a[scored] > iou_b[scored] + 0.05)),
        "b_better": int(np.count_nonzero(iou_b[scored] > iou_a[scored] + 0.05)),
        "mean_size_ratio_a_over_b": float(np.nanmean(
            np.sqrt(boxes_a[:, 2] * boxes_a[:, 3]) / np.sqrt(boxes_b[:, 2] * boxes_b[:, 3]))),
        "mean_aspect_a": float(np.nanmean(boxes_a[:, 2] / boxes_a[:, 3])),
        "mean_aspect_b": float(np.nanmean(boxes_b[:, 2] / boxes_b[:, 3])),
        "mean_aspect_gt": float(np.nanmean(groundtruth[:, 2] / groundtruth[:, 3])),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jsar.eval.compare", description=__doc__.split("\n\n")[0])
    parser.add_argument("result", type=Path, help="JSON written by python -m jsar.eval --json")
    parser.add_argument("sequence")
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--every", type=int, default=1, help="print every N-th frame (divergence always)")
    parser.add_argument("--min-iou", type=float, default=0.5, help="A and B 'apart' below this mutual IoU")
    args = parser.parse_args(argv)
    result = json.loads(args.result.read_text())
    sequences = result["sequences"]
    if args.sequence not in sequences:
        raise SystemExit(f"error: sequence {args.sequence!r} not in {', '.join(sequences)}")
    trackers = sequences[args.sequence]["trackers"]
    for name in (args.a, args.b):
        if name not in trackers:
            raise SystemExit(f"error: tracker {name!r} not in {args.sequence}: {', '.join(trackers)}")
    if "groundtruth" not in sequences[args.sequence]:
        raise SystemExit("error: this JSON has no ground truth per sequence; rerun python -m jsar.eval --json")
    gt = report.boxes_from_json(sequences[args.sequence]["groundtruth"])
    boxes_a = report.boxes_from_json(trackers[args.a]["boxes"])
    boxes_b = report.boxes_from_json(trackers[args.b]["boxes"])
    d = divergence(boxes_a, boxes_b, gt, args.min_iou)
    print(f"{args.sequence}: {args.a} vs {args.b}; AUC {trackers[args.a]['auc']:.3f} vs {trackers[args.b]['auc']:.3f}")
    print(f"first frame with IoU({args.a}, {args.b}) < {args.min_iou}: {d['first_apart']}; "
          f"frames apart: {d['frames_apart']}/{len(gt)}; {args.a} better on {d['a_better']}, "
          f"{args.b} better on {d['b_better']} frames (IoU margin 0.05)")
    print(f"mean size ratio {args.a}/{args.b}: {d['mean_size_ratio_a_over_b']:.3f}; mean aspect w/h "
          f"{args.a} {d['mean_aspect_a']:.3f}, {args.b} {d['mean_aspect_b']:.3f}, gt {d['mean_aspect_gt']:.3f}")
    print(f"{'frame':>5} {'IoU A':>6} {'IoU B':>6} {'IoU AB':>6}  {'A x,y,w,h':>28}  {'B x,y,w,h':>28}")
    for i in range(len(gt)):
        if i % max(args.every, 1) and i != d["first_apart"]:
            continue
        fmt = lambda b: ",".join(f"{v:.1f}" for v in b)  # noqa: E731
        cells = [f"{v:6.3f}" if not np.isnan(v) else "     -" for v in (d["iou_a"][i], d["iou_b"][i], d["iou_ab"][i])]
        print(f"{i:5d} {' '.join(cells)}  {fmt(boxes_a[i]):>28}  {fmt(boxes_b[i]):>28}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
