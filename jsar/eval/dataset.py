"""OTB-layout sequences and published result files.

A sequence folder holds `img/*.jpg` (frames in sorted order) and `groundtruth_rect.txt` (one
`x,y,w,h` line per frame, MATLAB 1-based pixels, `NaN` rows = target not visible). In memory every
box is 0-based (x, y, w, h) float64 pixels, top-left origin: the file's x and y minus 1.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

GROUNDTRUTH_FILE = "groundtruth_rect.txt"
IMAGE_DIR = "img"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")
_SEPARATORS = re.compile(r"[,\s]+")
_DIGITS = re.compile(r"(\d+)")


@dataclass(frozen=True)
class Sequence:
    """One sequence: frame paths in order and ground truth (N, 4) 0-based x,y,w,h, NaN rows = absent."""

    name: str
    frame_paths: tuple[Path, ...]
    groundtruth: np.ndarray

    def __post_init__(self) -> None:
        gt = np.asarray(self.groundtruth, dtype=np.float64)
        if gt.ndim != 2 or gt.shape[1] != 4:
            raise ValueError(f"{self.name}: ground truth must be (N, 4), got shape {gt.shape}")
        if gt.shape[0] != len(self.frame_paths):
            raise ValueError(
                f"{self.name}: {len(self.frame_paths)} frames but {gt.shape[0]} ground-truth rows")
        gt.setflags(write=False)
        object.__setattr__(self, "groundtruth", gt)

    def __len__(self) -> int:
        return len(self.frame_paths)

    def read_frame(self, index: int) -> np.ndarray:
        """Frame `index` as HxWx3 uint8 BGR (cv2.imread); ValueError if it cannot be decoded."""
        return read_image(self.frame_paths[index])


def read_image(path: Path) -> np.ndarray:
    """Decode an image file to HxWx3 uint8 BGR; ValueError naming the file if it cannot be read."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"cannot decode image {path}")
    return image


def natural_key(path: Path) -> list[object]:
    """Sort key that orders 'frame2.jpg' before 'frame10.jpg' (digit runs compared as numbers)."""
    return [int(part) if part.isdigit() else part for part in _DIGITS.split(path.name)]


def parse_boxes(text: str, source: str) -> np.ndarray:
    """Parse x,y,w,h lines (comma, tab or space separated; NaN allowed) -> (N, 4) float64 as written.

    Blank lines are skipped; any other line that is not four numbers raises ValueError naming
    `source` and the 1-based line number. A row with some but not all values NaN is malformed.
    """
    rows: list[list[float]] = []
    for line_number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        fields = [f for f in _SEPARATORS.split(stripped) if f]
        if len(fields) != 4:
            raise ValueError(f"{source}:{line_number}: expected 4 values x,y,w,h, got {stripped!r}")
        try:
            values = [float(f) for f in fields]
        except ValueError as exc:
            raise ValueError(f"{source}:{line_number}: not a number in {stripped!r}") from exc
        nan_count = sum(math.isnan(v) for v in values)
        if nan_count not in (0, 4):
            raise ValueError(f"{source}:{line_number}: partly NaN box {stripped!r} (all four or none)")
        if any(math.isinf(v) for v in values):
            raise ValueError(f"{source}:{line_number}: infinite value in {stripped!r}")
        rows.append(values)
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def one_based_to_zero_based(boxes: np.ndarray) -> np.ndarray:
    """MATLAB 1-based (x, y, w, h) -> 0-based: x - 1, y - 1, size unchanged (NaN rows stay NaN)."""
    return np.asarray(boxes, dtype=np.float64) - np.array([1.0, 1.0, 0.0, 0.0])


def zero_based_to_one_based(boxes: np.ndarray) -> np.ndarray:
    """0-based (x, y, w, h) -> MATLAB 1-based: x + 1, y + 1 (for writing result files)."""
    return np.asarray(boxes, dtype=np.float64) + np.array([1.0, 1.0, 0.0, 0.0])


def is_sequence_dir(folder: Path) -> bool:
    """True if `folder` has both an img/ directory and a groundtruth_rect.txt file."""
    return (folder / IMAGE_DIR).is_dir() and (folder / GROUNDTRUTH_FILE).is_file()


def load_sequence(folder: Path | str) -> Sequence:
    """Load one OTB-layout folder; ValueError on missing img/ or ground truth, no frames, count mismatch."""
    folder = Path(folder)
    image_dir = folder / IMAGE_DIR
    gt_path = folder / GROUNDTRUTH_FILE
    if not image_dir.is_dir():
        raise ValueError(f"sequence {folder}: missing {IMAGE_DIR}/ directory")
    if not gt_path.is_file():
        raise ValueError(f"sequence {folder}: missing {GROUNDTRUTH_FILE}")
    frames = sorted(
        (p for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)
    if not frames:
        raise ValueError(f"sequence {folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in {IMAGE_DIR}/")
    boxes = parse_boxes(gt_path.read_text(), str(gt_path))
    if boxes.shape[0] != len(frames):
        raise ValueError(
            f"sequence {folder}: {len(frames)} frames in {IMAGE_DIR}/ but {boxes.shape[0]} boxes in "
            f"{GROUNDTRUTH_FILE}")
    visible = ~np.isnan(boxes[:, 0])
    if np.any(boxes[visible, 2:] <= 0):
        bad = int(np.flatnonzero(visible & np.any(boxes[:, 2:] <= 0, axis=1))[0]) + 1
        raise ValueError(f"{gt_path}:{bad}: non-positive box size")
    return Sequence(folder.name, tuple(frames), one_based_to_zero_based(boxes))


def discover_sequences(root: Path | str) -> list[Path]:
    """Sequence folders under `root` (root itself if it is one, else its direct children), by name.

    A child holding only one of img/ and groundtruth_rect.txt is an incomplete sequence: ValueError.
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"data root {root} is not a directory")
    if is_sequence_dir(root):
        return [root]
    found: list[Path] = []
    for child in sorted(root.iterdir(), key=lambda p: p.name):
        if not child.is_dir():
            continue
        has_images = (child / IMAGE_DIR).is_dir()
        has_gt = (child / GROUNDTRUTH_FILE).is_file()
        if has_images and has_gt:
            found.append(child)
        elif has_images or has_gt:
            missing = GROUNDTRUTH_FILE if has_images else f"{IMAGE_DIR}/"
            raise ValueError(f"sequence {child}: incomplete, missing {missing}")
    if not found:
        raise ValueError(f"no sequence folders (img/ + {GROUNDTRUTH_FILE}) under {root}")
    return found


def select_sequences(folders: list[Path], names: list[str] | None) -> list[Path]:
    """Keep the folders named in `names` (in that order); ValueError naming any unknown name."""
    if not names:
        return folders
    by_name = {f.name: f for f in folders}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise ValueError(f"unknown sequence(s) {', '.join(unknown)}; available: {', '.join(by_name)}")
    return [by_name[n] for n in names]


def published_trackers(directory: Path | str) -> list[str]:
    """Tracker names with a results folder under `directory` (DIR/<tracker>/<seq>.txt), sorted."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"published results directory {directory} does not exist")
    return sorted(p.name for p in directory.iterdir() if p.is_dir())


def load_published(directory: Path | str, tracker: str, sequence: str, n_frames: int) -> np.ndarray | None:
    """Published boxes DIR/<tracker>/<sequence>.txt -> (n_frames, 4) 0-based x,y,w,h, or None if absent.

    The file is 1-based MATLAB x,y,w,h (comma or whitespace separated), frame 1 = the initial box.
    A row count different from the sequence's frame count is a ValueError: a shorter file cannot
    be aligned to frames honestly (we would not know which frames are missing).
    """
    path = Path(directory) / tracker / f"{sequence}.txt"
    if not path.is_file():
        return None
    boxes = parse_boxes(path.read_text(), str(path))
    if boxes.shape[0] != n_frames:
        raise ValueError(f"{path}: {boxes.shape[0]} rows but the sequence has {n_frames} frames")
    return one_based_to_zero_based(boxes)
