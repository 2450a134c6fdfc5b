"""Colour channels on / off: `python -m bench.colour_ab DATA_ROOT [--table FILE.npy | --sigma S] [--json FILE]`.

Runs the "jsar" tracker one-pass over every sequence under DATA_ROOT twice, with the colour
attributes (42 channels; the derived table, --sigma: derived with another softness, or --table: an
external table) and without them (32 channels), and prints
precision at 20 px and success AUC per sequence and their means. Accuracy only: the fps column
counts tracker time, but for speed comparisons use `python -m jsar.eval`, which runs OpenCV's
trackers in the same run.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import jsar
from jsar.eval.dataset import discover_sequences, load_sequence
from jsar.eval.metrics import score
from jsar.features.colour import derived_colour_table


def track_sequence(folder: Path, overrides: dict[str, object]) -> dict[str, float]:
    """One-pass run of jsar with `overrides` from the first ground-truth box: precision, auc, fps."""
    seq = load_sequence(folder)
    frames = [seq.read_frame(i) for i in range(len(seq))]
    tracker = jsar.create("jsar", **overrides)
    boxes = np.full((len(seq), 4), np.nan)
    boxes[0] = seq.groundtruth[0]
    start = time.perf_counter()
    tracker.init(frames[0], tuple(float(v) for v in seq.groundtruth[0]))
    for index in range(1, len(seq)):
        boxes[index] = tracker.update(frames[index]).box
    elapsed = time.perf_counter() - start
    scores = score(boxes, seq.groundtruth)
    return {"precision": round(float(scores["precision"]), 3), "auc": round(float(scores["auc"]), 3),
            "fps": round(len(seq) / elapsed, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", type=Path)
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--table", help="external colour table .npy (32768x10 or 32768x11) instead of the derived one")
    source.add_argument("--sigma", type=float, help="derive the table with this CIELAB softness instead of the default")
    parser.add_argument("--colour-only", action="store_true", help="skip the run without colour channels")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    try:
        folders = discover_sequences(args.data_root)
    except ValueError as exc:
        parser.error(str(exc))
    if not folders:
        parser.error(f"no sequences under {args.data_root}")
    with tempfile.TemporaryDirectory() as scratch:
        table_path = args.table
        if args.sigma is not None:
            if not args.sigma > 0:
                parser.error("--sigma must be positive")
            table_path = str(Path(scratch) / "derived.npy")
            np.save(table_path, derived_colour_table(args.sigma))
        results = compare(folders, table_path, with_baseline=not args.colour_only)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


def compare(folders: list[Path], table_path: str | None, with_baseline: bool = True) -> dict[str, dict[str, object]]:
    """Colour (and, with_baseline, no-colour) runs over all folders; prints rows and means, returns them."""
    variants: dict[str, dict[str, object]] = {"colour": {"use_colour": True, "colour_table_path": table_path}}
    if with_baseline:
        variants["no-colour"] = {"use_colour": False}
    results: dict[str, dict[str, object]] = {}
    for name, overrides in variants.items():
        rows = {folder.name: track_sequence(folder, overrides) for folder in folders}
        for seq_name, row in rows.items():
            print(f"{name:10s} {seq_name:28s} precision {row['precision']:.3f}  AUC {row['auc']:.3f}  {row['fps']:6.1f} fps")
        mean_precision = float(np.mean([r["precision"] for r in rows.values()]))
        mean_auc = float(np.mean([r["auc"] for r in rows.values()]))
        print(f"{name:10s} {'MEAN':28s} precision {mean_precision:.3f}  AUC {mean_auc:.3f}")
        results[name] = {"sequences": rows, "mean_precision": round(mean_precision, 3), "mean_auc": round(mean_auc, 3)}
    return results


if __name__ == "__main__":
    sys.exit(main())
