"""python -m jsar.demo [--sequence DIR] [--tracker jsar] [--out out/demo] [--max-frames N]

Track one sequence and write an annotated video (MJPG .avi), a per-frame CSV log
(frame, x, y, w, h, score, state, ms; boxes 0-based pixels) and print the tracker's fps.
The sequence is --sequence, else one from $JSAR_DATA_ROOT (OTB layout), else a synthetic clip
made in code (a textured red object moving over a grey textured background).
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

import jsar
from jsar.api import Box
from jsar.eval import dataset
from jsar.eval.runner import cap_loaded_pools, limit_threads_env
from jsar.eval.synthetic import synthetic_clip

DEFAULT_REAL_SEQUENCE = "UAV123_10fps_wakeboard7"  # short (67 frames), small target on water
STATE_COLOURS = {"tracking": (0, 220, 0), "lost": (0, 0, 255), "recovered": (0, 220, 255)}  # BGR


def choose_source(sequence: Path | None, data_root: str | None) -> tuple[str, list[np.ndarray] | None,
                                                                           dataset.Sequence | None, np.ndarray]:
    """(name, frames if synthetic, sequence if real, 0-based ground truth) per the precedence above."""
    if sequence is not None:
        seq = dataset.load_sequence(sequence)
        return seq.name, None, seq, seq.groundtruth
    if data_root:
        folders = dataset.discover_sequences(data_root)
        by_name = {f.name: f for f in folders}
        seq = dataset.load_sequence(by_name.get(DEFAULT_REAL_SEQUENCE, folders[0]))
        return seq.name, None, seq, seq.groundtruth
    frames, boxes = synthetic_clip(n_frames=120, size=(360, 480), object_size=(40, 30))
    return "synthetic", frames, None, boxes


def annotate(frame: np.ndarray, box: Box, gt: np.ndarray, state: str,
             index: int, ms: float) -> np.ndarray:
    """Copy of `frame` with the ground truth (thin white), the tracker box (colour = state) and a caption."""
    out = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if not np.any(np.isnan(gt)):
        x, y, w, h = (int(round(v)) for v in gt)
        cv2.rectangle(out, (x, y), (x + w, y + h), (255, 255, 255), 1)
    x, y, w, h = (int(round(v)) for v in box)
    cv2.rectangle(out, (x, y), (x + w, y + h), STATE_COLOURS.get(state, (255, 0, 255)), 2)
    caption = f"#{index} {state} {ms:.1f} ms"
    cv2.putText(out, caption, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, caption, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def run_demo(tracker_name: str, out_dir: Path, sequence: Path | None, data_root: str | None,
             max_frames: int | None = None) -> dict[str, object]:
    """Track, write <out>/<name>_<tracker>.avi and .csv; return a summary (frames, fps, paths)."""
    name, frames, seq, gt = choose_source(sequence, data_root)
    n = len(gt) if max_frames is None else min(len(gt), max_frames)
    if np.any(np.isnan(gt[0])):
        raise ValueError(f"{name}: the target must be visible in the first frame")
    tracker = jsar.create(tracker_name)
    cap_loaded_pools()  # after create(): the tracker's libraries are loaded; fps is for one thread
    out_dir.mkdir(parents=True, exist_ok=True)
    video_path = out_dir / f"{name}_{tracker_name}.avi"
    csv_path = out_dir / f"{name}_{tracker_name}.csv"
    writer: cv2.VideoWriter | None = None
    tracker_seconds = 0.0
    try:
        with csv_path.open("w", newline="") as handle:
            log = csv.writer(handle)
            log.writerow(["frame", "x", "y", "w", "h", "score", "state", "ms"])
            for index in range(n):
                frame = frames[index] if frames is not None else seq.read_frame(index)  # type: ignore[union-attr]
                start = time.perf_counter()
                if index == 0:
                    box0 = tuple(float(v) for v in gt[0])
                    tracker.init(frame, box0)
                    box, score, state = box0, 1.0, "tracking"
                else:
                    result = tracker.update(frame)
                    box, score, state = result.box, result.score, result.state
                seconds = time.perf_counter() - start
                tracker_seconds += seconds
                log.writerow([index, *(f"{v:.2f}" for v in box), f"{score:.4f}", state, f"{seconds * 1e3:.2f}"])
                if writer is None:
                    height, width = frame.shape[:2]
                    writer = cv2.VideoWriter(str(video_path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (width, height))
                    if not writer.isOpened():
                        raise ValueError(f"cannot open an MJPG video writer for {video_path}")
                writer.write(annotate(frame, box, gt[index], state, index, seconds * 1e3))
    finally:
        if writer is not None:
            writer.release()
    fps = n / tracker_seconds if tracker_seconds > 0 else float("nan")
    return {"sequence": name, "tracker": tracker_name, "frames": n, "fps": fps,
            "video": video_path, "log": csv_path}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jsar.demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequence", type=Path, help="an OTB-layout sequence folder (img/ + groundtruth_rect.txt)")
    parser.add_argument("--tracker", default="jsar", help=f"one of {', '.join(jsar.available())}")
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    parser.add_argument("--max-frames", type=int, help="stop after N frames")
    args = parser.parse_args(argv)
    limit_threads_env()
    try:
        summary = run_demo(args.tracker, args.out, args.sequence, os.environ.get("JSAR_DATA_ROOT"), args.max_frames)
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from exc
    print(f"{summary['tracker']} on {summary['sequence']}: {summary['frames']} frames, "
          f"{summary['fps']:.1f} fps (tracker time only)")
    print(f"video: {summary['video']}\nlog:   {summary['log']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
