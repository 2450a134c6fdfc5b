"""Cost of the learnt features (jsar.learnt) per call on one thread: OpenCV DNN against onnxruntime.

    python -m bench.learnt [--repeats 30]                 # cost per call
    python -m bench.learnt --separation DATA_ROOT        # does the embedding tell the target from others

Cost: the median (and minimum) milliseconds per call for a batch of 1 and 16 64x64 crops, and for a 256x256 and a
384x384 gate, at both cuts (stride 8 and 16), and for the same gate sizes alternating (the tracker's
gate changes size from frame to frame: a runtime that re-plans per shape pays for it).

Separation, per embedding variant (cut, pooling, context), on every sequence of DATA_ROOT: the target's
embedding (ground-truth box) in a frame t0 against, in a later frame t1 = t0 + gap, the target's own and
16 windows of its size that do not overlap it, `near` (centres within 4 box sizes) or anywhere in the
frame. Cosine distances (1 - cos); `wins` = share of (t0, t1) pairs where the target in t1 is closer than
every one of the 16 windows; `pairs` = share of (pair, window) where it is closer than that window.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np

from jsar.learnt.embedding import embed, feature_map, match_map, target_template
from jsar.learnt.mobilenet import BACKENDS, FeatureNet, to_blob

GAPS = (5, 20, 50)  # frames between the reference and the later frame


def timed_ms(call, repeats: int) -> str:
    """'median (min)' wall-clock ms of call() over `repeats` calls after one warm-up (the minimum: the cost
    without other processes' interference on a shared machine)."""
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return f"{1e3 * float(np.median(times)):7.2f} ({1e3 * min(times):6.2f})"


def cycling(net: FeatureNet, blobs: list[np.ndarray]):
    """A call of net.run_blob on the next of blobs each time (all of them once first)."""
    for blob in blobs:
        net.run_blob(blob)
    state = {"i": 0}

    def call() -> None:
        net.run_blob(blobs[state["i"] % len(blobs)])
        state["i"] += 1
    return call


def other_windows(rng: np.random.Generator, frame_hw: tuple[int, int], box: np.ndarray, count: int,
                  near: bool) -> np.ndarray:
    """(count, 4) boxes x, y, w, h px of the target's size, inside the frame, not overlapping `box`;
    `near`: centres within 4 box sizes of the target's."""
    x, y, w, h = box
    fh, fw = frame_hw
    out: list[tuple[float, float, float, float]] = []
    for _ in range(200 * count):
        if len(out) == count:
            break
        if near:
            nx, ny = x + rng.uniform(-4, 4) * w, y + rng.uniform(-4, 4) * h
        else:
            nx, ny = rng.uniform(0, fw - w), rng.uniform(0, fh - h)
        inside = 0 <= nx <= fw - w and 0 <= ny <= fh - h
        apart = nx + w <= x or x + w <= nx or ny + h <= y or y + h <= ny
        if inside and apart:
            out.append((nx, ny, w, h))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def pair_frames(groundtruth: np.ndarray) -> list[tuple[int, int]]:
    """(t0, t1) pairs: t0 the first frame and a third of the way in, t1 = t0 + each gap, target visible in both."""
    n = len(groundtruth)
    pairs = []
    for t0 in (0, n // 3):
        for gap in GAPS:
            t1 = t0 + gap
            if t1 < n and not np.isnan(groundtruth[t0]).any() and not np.isnan(groundtruth[t1]).any():
                pairs.append((t0, t1))
    return pairs


def separation(net: FeatureNet, data_root: Path, near: bool, seed: int = 0, **embed_options) -> dict[str, float]:
    """Medians of the shift (2 px diagonal), self and others' distances, and the wins / pairs shares."""
    from jsar.eval.dataset import load_sequence

    rng = np.random.default_rng(seed)
    shift, own, others, wins, pairs = [], [], [], [], []
    for folder in sorted(p for p in data_root.iterdir() if (p / "groundtruth_rect.txt").is_file()):
        seq = load_sequence(folder)
        for t0, t1 in pair_frames(seq.groundtruth):
            f0, f1 = seq.read_frame(t0), seq.read_frame(t1)
            box0, box1 = seq.groundtruth[t0], seq.groundtruth[t1]
            shifted = box0 + np.array([[2, 2, 0, 0], [-2, 2, 0, 0], [2, -2, 0, 0], [-2, -2, 0, 0]])
            e0 = embed(net, f0, np.vstack([box0, shifted]), **embed_options)
            negatives = other_windows(rng, f1.shape[:2], box1, 16, near)
            e1 = embed(net, f1, np.vstack([box1, negatives]), **embed_options)
            d_shift = 1 - e0[1:] @ e0[0]
            d1 = 1 - e1 @ e0[0]
            shift.extend(d_shift)
            own.append(d1[0])
            others.extend(d1[1:])
            wins.append(bool(d1[0] < d1[1:].min()))
            pairs.extend(d1[0] < d1[1:])
    return {"shift": float(np.median(shift)), "self": float(np.median(own)), "others": float(np.median(others)),
            "others_p10": float(np.percentile(others, 10)), "wins": float(np.mean(wins)),
            "pairs": float(np.mean(pairs)), "n": len(wins)}


def report_separation(data_root: Path) -> None:
    """Print separation() for each cut, pooling and context, near and anywhere windows."""
    print(f"{'variant':34s} {'windows':8s} shift  self  others(p10)  wins  pairs   (n pairs)")
    for cut in (8, 16):
        net = FeatureNet(cut, "onnxruntime")
        for size in (64, 96):
            for context in (0.25, 0.5):
                for pooling in ("mean", "grid", "mean+grid"):
                    for near in (True, False):
                        r = separation(net, data_root, near, size=size, context=context, pooling=pooling)
                        name = f"stride {cut} size {size} ctx {context} {pooling}"
                        print(f"{name:34s} {'near' if near else 'anywhere':8s} {r['shift']:.3f} {r['self']:.3f} "
                              f"{r['others']:.3f}({r['others_p10']:.3f}) {r['wins']:.2f}  {r['pairs']:.2f}   ({r['n']})",
                              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--separation", type=Path, metavar="DATA_ROOT",
                        help="measure the embedding's separation on the OTB-layout sequences there instead of cost")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.separation:
        report_separation(args.separation)
        return
    rng = np.random.default_rng(0)
    cases = {
        "crop 64x64, batch 1": [to_blob(rng.integers(0, 256, (1, 64, 64, 3), dtype=np.uint8))],
        "crop 64x64, batch 16": [to_blob(rng.integers(0, 256, (16, 64, 64, 3), dtype=np.uint8))],
        "gate 256x256": [to_blob(rng.integers(0, 256, (256, 256, 3), dtype=np.uint8))],
        "gate 384x384": [to_blob(rng.integers(0, 256, (384, 384, 3), dtype=np.uint8))],
        "gate 256..384 alternating": [to_blob(rng.integers(0, 256, (s, s + 8, 3), dtype=np.uint8))
                                      for s in (256, 320, 384, 288)],
    }
    print(f"opencv {cv2.__version__}; ms per call, median (min) of {args.repeats}, one thread")
    frame = cv2.resize(rng.integers(0, 256, (90, 160, 3), dtype=np.uint8), (1280, 720), interpolation=cv2.INTER_CUBIC)
    boxes = np.column_stack([rng.uniform(0, 1200, 16), rng.uniform(0, 650, 16), rng.uniform(20, 80, (16, 2))])
    for cut in (8, 16):
        nets = {backend: FeatureNet(cut, backend) for backend in BACKENDS}
        for name, blobs in cases.items():
            cells = "  ".join(f"{backend} {timed_ms(cycling(net, blobs), args.repeats)}" for backend, net in nets.items())
            print(f"stride {cut:2d}  {name:28s} {cells}")
        net = nets["onnxruntime"]
        # whole calls on a 1280 x 720 frame: crops + pass + pooling; a 384 x 384 gate's map + its match map
        template = target_template(net, frame, (600.0, 300.0, 48.0, 48.0), 4 * cut / 48)
        fmap = feature_map(net, frame, (400.0, 100.0, 384.0, 384.0), 1.0)
        calls = {"embed 1 box (crop, pass, pool)": lambda: embed(net, frame, boxes[:1]),
                 "embed 16 boxes": lambda: embed(net, frame, boxes),
                 "match_map, 384 gate, 4x4 template": lambda: match_map(fmap, template)}
        for name, call in calls.items():
            print(f"stride {cut:2d}  {name:34s} onnxruntime {timed_ms(call, args.repeats)}")


if __name__ == "__main__":
    main()
