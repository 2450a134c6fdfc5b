"""A small synthetic clip made in code: a textured red object moving over a grey textured background.

Used by the demo when no real data is present and by tests (written as an OTB-layout folder).
The background is grey (B = G = R) and the object strongly red, so tests can tell object pixels
from background pixels by colour alone.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from jsar.eval.dataset import GROUNDTRUTH_FILE, IMAGE_DIR, zero_based_to_one_based


def grey_texture(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """HxW uint8 smooth random texture in [40, 200] (blurred noise at two scales)."""
    coarse = cv2.resize(rng.random((max(2, height // 16), max(2, width // 16))).astype(np.float32),
                        (width, height), interpolation=cv2.INTER_CUBIC)
    fine = cv2.GaussianBlur(rng.random((height, width)).astype(np.float32), (0, 0), 1.5)
    mix = 0.6 * coarse + 0.4 * fine
    mix = (mix - mix.min()) / max(float(np.ptp(mix)), 1e-6)
    return (40 + 160 * mix).astype(np.uint8)


def synthetic_clip(n_frames: int = 60, size: tuple[int, int] = (240, 320), object_size: tuple[int, int] = (36, 28),
                   seed: int = 0, period: int = 120) -> tuple[list[np.ndarray], np.ndarray]:
    """Frames (HxWx3 uint8 BGR) and 0-based (x, y, w, h) ground truth of an object on a Lissajous path.

    size is (height, width); object_size is (w, h) in pixels; one loop of the path takes `period` frames. The background drifts slowly (camera
    motion) and the object's red texture is fixed, so any tracker has something to learn.
    """
    height, width = size
    ow, oh = object_size
    if ow * 2 >= width or oh * 2 >= height:
        raise ValueError(f"object {object_size} too large for a {width}x{height} frame")
    rng = np.random.default_rng(seed)
    background = grey_texture(height + 40, width + 40, rng)
    pattern = rng.integers(0, 2, size=(max(1, oh // 4), max(1, ow // 4))).astype(np.float32)
    pattern = cv2.resize(pattern, (ow, oh), interpolation=cv2.INTER_NEAREST)
    obj = np.zeros((oh, ow, 3), np.uint8)
    obj[..., 2] = 255  # red: B, G low, R saturated
    obj[..., 1] = (pattern * 50).astype(np.uint8)
    obj[..., 0] = (pattern * 30).astype(np.uint8)
    frames: list[np.ndarray] = []
    boxes = np.zeros((n_frames, 4))
    cx, cy = (width - ow) / 2, (height - oh) / 2
    ax, ay = (width - ow) / 2 - 10, (height - oh) / 2 - 10
    for t in range(n_frames):
        phase = 2 * np.pi * t / max(period, 1)
        x = int(round(cx + ax * np.sin(phase)))
        y = int(round(cy + ay * np.sin(2 * phase) * 0.8))
        shift = int(round(20 + 15 * np.sin(phase / 2)))
        frame = cv2.cvtColor(background[shift:shift + height, shift // 2:shift // 2 + width], cv2.COLOR_GRAY2BGR)
        frame[y:y + oh, x:x + ow] = obj
        frames.append(frame)
        boxes[t] = (x, y, ow, oh)
    return frames, boxes


def write_otb_sequence(folder: Path | str, frames: list[np.ndarray], boxes: np.ndarray,
                       separator: str = ",") -> Path:
    """Write frames as img/0001.jpg.. and 0-based boxes as a 1-based groundtruth_rect.txt; returns folder."""
    folder = Path(folder)
    (folder / IMAGE_DIR).mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames, start=1):
        if not cv2.imwrite(str(folder / IMAGE_DIR / f"{index:04d}.jpg"), frame, [cv2.IMWRITE_JPEG_QUALITY, 95]):
            raise ValueError(f"cannot write frame {index} into {folder}")
    lines = [separator.join("NaN" if np.isnan(v) else f"{v:g}" for v in row)
             for row in zero_based_to_one_based(boxes)]
    (folder / GROUNDTRUTH_FILE).write_text("\n".join(lines) + "\n")
    return folder
