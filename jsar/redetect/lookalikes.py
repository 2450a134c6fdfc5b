"""Look-alikes seen while tracking: a nearest-neighbour check on re-detection candidates.

The decision filter and the colour check judge a candidate against the target alone: a look-alike of
the target's layout and colours (another walker in the group, another car in the queue) passes both.
While the target is tracked, such look-alikes show as secondary peaks of the core's response in its
search window (5 target sides). Their appearances are kept as negatives, the target's as positives;
a candidate counts as the target only when it is nearer (cosine similarity of appearance descriptors)
to some target appearance than to every look-alike by `margin`: TLD's nearest-neighbour classifier, fed
with the hard negatives the correlation filter itself ranks as look-alikes.

Conventions: boxes (x, y, w, h) px; frames uint8 HxWx3 BGR or HxW grey; response maps (H, W) in cells
with the peak position the displacement (wrapped), as jsar_tracker.Localisation.response.
"""
from __future__ import annotations

import collections
import math

import cv2
import numpy as np

from jsar.features import patches
from jsar.features.translation import extract_features

Box = tuple[float, float, float, float]
DESCRIPTOR_CELLS = 6  # descriptor grid: the box resampled to 6 x 6 cells of 4 px
DESCRIPTOR_CELL_PX = 4


def appearance_descriptor(frame: np.ndarray, box: Box, colour_table: np.ndarray | None) -> np.ndarray:
    """(D,) float32 unit vector: the translation features (gray, fHOG, colour names) of `box` (x, y, w, h
    px) resampled to DESCRIPTOR_CELLS^2 cells, mean removed per channel (a uniform change of light
    or contrast moves little)."""
    x, y, w, h = box
    out = DESCRIPTOR_CELLS * DESCRIPTOR_CELL_PX
    patch = patches.sample_patch(frame, (x + w / 2.0, y + h / 2.0), (max(w, 1.0), max(h, 1.0)), (out, out))
    features = extract_features(patch, DESCRIPTOR_CELL_PX, colour_table)
    features = features - features.mean(axis=(0, 1), keepdims=True)
    vector = features.ravel()
    norm = float(np.linalg.norm(vector))
    return vector / norm if norm > 0 else vector


def secondary_peaks(response: np.ndarray, target_cells: tuple[float, float], min_fraction: float,
                    max_peaks: int) -> list[tuple[float, float, float]]:
    """Up to max_peaks local maxima (dy, dx cells from the sample centre, value) of a wrapped response
    map, strongest first, at least one target size (target_cells (h, w)) from the main peak along some
    axis and at least min_fraction x the main peak's value (a positive main peak only)."""
    peak = float(response.max())
    if peak <= 0 or max_peaks <= 0:
        return []
    height, width = response.shape
    centred = np.fft.fftshift(response)  # the sample centre at (height // 2, width // 2)
    local_max = centred >= cv2.dilate(centred, np.ones((3, 3), np.uint8))
    main_y, main_x = np.unravel_index(int(np.argmax(centred)), centred.shape)
    ys, xs = np.nonzero(local_max & (centred >= min_fraction * peak))
    far = (np.abs(ys - main_y) >= target_cells[0]) | (np.abs(xs - main_x) >= target_cells[1])
    ys, xs = ys[far], xs[far]
    order = np.argsort(-centred[ys, xs])[:max_peaks]
    return [(float(ys[k] - height // 2), float(xs[k] - width // 2), float(centred[ys[k], xs[k]])) for k in order]


def nearest_similarity(descriptor: np.ndarray, bank: collections.deque[np.ndarray] | list[np.ndarray]) -> float:
    """The largest cosine similarity of a unit descriptor with the bank's (-inf for an empty bank)."""
    if not bank:
        return -math.inf
    return float(np.max(np.stack(list(bank)) @ descriptor))


class LookalikeBank:
    """The target's appearances (positives: the first kept for good, then up to `size` recent) and the
    look-alikes' (negatives, up to `size`), as unit descriptors; `margin(descriptor)` = nearest positive
    similarity minus nearest negative similarity."""

    def __init__(self, size: int) -> None:
        self.first: np.ndarray | None = None
        self.positives: collections.deque[np.ndarray] = collections.deque(maxlen=size)
        self.negatives: collections.deque[np.ndarray] = collections.deque(maxlen=size)

    def add_positive(self, descriptor: np.ndarray) -> None:
        """Remember a target appearance (the first one is never forgotten)."""
        if self.first is None:
            self.first = descriptor
        else:
            self.positives.append(descriptor)

    def add_negative(self, descriptor: np.ndarray) -> None:
        """Remember a look-alike's appearance."""
        self.negatives.append(descriptor)

    def similarities(self, descriptor: np.ndarray) -> tuple[float, float]:
        """(nearest positive, nearest negative) cosine similarities (-inf where a bank is empty)."""
        positives = list(self.positives) + ([self.first] if self.first is not None else [])
        return nearest_similarity(descriptor, positives), nearest_similarity(descriptor, self.negatives)

    def margin(self, descriptor: np.ndarray) -> float:
        """Nearest positive minus nearest negative similarity (inf without negatives: nothing to tell apart)."""
        positive, negative = self.similarities(descriptor)
        return positive - negative if math.isfinite(negative) else math.inf
