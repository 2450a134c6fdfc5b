"""A colour check on re-detection candidates: does a candidate box have the target's colours?

A second test, independent of the decision filter's layout-bound template, on a candidate that passed the
acceptance bar. Two measures, each relative to its running mean on the boxes the model learnt; a
candidate's match is the larger:
- similarity: the Bhattacharyya coefficient of the box's joint colour histogram with the target's;
- share: the fraction of the box's pixels in colours where P(target | colour) > 1/2, from the histograms
  of the target's box and its surround (the box enlarged `surround_scale` times per side, without it).
Why two measures (each alone failed on the evaluation sets): docs/method.md ("JSAR-Re").
Conventions: boxes (x, y, w, h) px; frames uint8 HxWx3 (any channel order, used as given) or HxW;
histograms are joint histograms of `bins` levels per channel, normalised to sum 1.
"""
from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from jsar.api import Box
from jsar.redetect.monitor import updated_reference
MAX_PIXELS = 4096  # a histogram of up to 8^3 bins needs no more: larger regions are sampled on a grid


def region_pixels(frame: np.ndarray, box: Box, scale: float = 1.0,
                  max_pixels: int = MAX_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (N, C) or (N,) of `box` (x, y, w, h px) enlarged `scale` times per side about its
    centre, rounded to whole pixels and clipped to the frame, every k-th row and column with the
    smallest k that keeps at most about max_pixels; and (N,) whether each lies inside the unenlarged box."""
    x, y, w, h = box
    cx, cy = x + w / 2.0, y + h / 2.0
    height, width = frame.shape[:2]
    x0, y0 = max(int(round(cx - scale * w / 2.0)), 0), max(int(round(cy - scale * h / 2.0)), 0)
    x1, y1 = min(int(round(cx + scale * w / 2.0)), width), min(int(round(cy + scale * h / 2.0)), height)
    if x1 <= x0 or y1 <= y0:
        return frame[:0, :0].reshape((0,) + frame.shape[2:]), np.empty(0, bool)
    step = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / max_pixels)))
    rows, cols = np.arange(y0, y1, step), np.arange(x0, x1, step)
    region = frame[y0:y1:step, x0:x1:step]
    inside_rows = (rows >= round(y)) & (rows < round(y + h))
    inside_cols = (cols >= round(x)) & (cols < round(x + w))
    inside = inside_rows[:, None] & inside_cols[None, :]
    return region.reshape((-1,) + frame.shape[2:]), inside.ravel()


@functools.lru_cache(maxsize=None)
def _levels(bins: int) -> np.ndarray:
    """(256,) the level (v * bins) >> 8 of each uint8 value v (read-only: shared by every call)."""
    levels = (np.arange(256, dtype=np.intp) * bins) >> 8
    levels.flags.writeable = False
    return levels


def colour_index(pixels: np.ndarray, bins: int) -> np.ndarray:
    """(N,) bin of each uint8 pixel (N, C) or (N,) in a joint histogram of `bins` levels per channel: level
    (v * bins) >> 8 per channel, channel 0 most significant."""
    levels = _levels(bins)  # one table lookup a value, not a cast, product and shift
    if pixels.ndim == 1:
        return levels[pixels]
    index = levels[pixels[:, 0]]
    for c in range(1, pixels.shape[1]):
        index = index * bins + levels[pixels[:, c]]
    return index


def normalised(counts: np.ndarray) -> np.ndarray | None:
    """Counts as a histogram summing to 1 (None for no counts)."""
    counts = counts.astype(np.float64)
    total = counts.sum()
    return counts / total if total > 0 else None


def histogram(pixels: np.ndarray, bins: int) -> np.ndarray | None:
    """Joint histogram (bins^C,) of uint8 pixels (N, C) or (N,), summing to 1 (None for no pixels)."""
    if len(pixels) == 0:
        return None
    channels = 1 if pixels.ndim == 1 else pixels.shape[1]
    return normalised(np.bincount(colour_index(pixels, bins), minlength=bins ** channels))


def split_histograms(pixels: np.ndarray, inside: np.ndarray, bins: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """histogram(pixels[inside], bins) and histogram(pixels[~inside], bins), from one bincount."""
    size = bins ** (1 if pixels.ndim == 1 else pixels.shape[1])
    counts = np.bincount(colour_index(pixels, bins) + np.where(inside, 0, size), minlength=2 * size)
    return normalised(counts[:size]), normalised(counts[size:])


def bhattacharyya(p: np.ndarray, q: np.ndarray) -> float:
    """Bhattacharyya coefficient sum(sqrt(p q)) of two normalised histograms of the same shape, in [0, 1]."""
    return float(np.sqrt(p * q).sum())


def target_colours(object_hist: np.ndarray, surround_hist: np.ndarray, surround_prior: float) -> np.ndarray:
    """(bins,) bool: the colours where P(target | colour) > 1/2, i.e. object_hist > surround_prior x
    surround_hist (histograms normalised; surround_prior = surround area / object area). A colour seen in
    neither is not the target's."""
    return object_hist > surround_prior * surround_hist


class ColourModel:
    """The target's colours and its surround's, learnt on the frames the decision filter learns
    (histograms blended in at `rate`), with the running means (`reference_rate`) of both measures on the
    learnt boxes: `similarity_reference` and `share_reference`."""

    def __init__(self, bins: int, rate: float, reference_rate: float, surround_scale: float) -> None:
        self.bins = bins
        self.rate = rate
        self.reference_rate = reference_rate
        self.surround_scale = surround_scale
        self.surround_prior = surround_scale ** 2 - 1.0  # the ring's area over the box's
        self.object_hist: np.ndarray | None = None
        self.surround_hist: np.ndarray | None = None
        self.similarity_reference: float | None = None
        self.share_reference: float | None = None

    def learn(self, frame: np.ndarray, box: Box) -> None:
        """Blend the histograms of `box` and of its surround in `frame` into the model, then update both
        references with the box's measures (a box without pixels in the frame, or without surround,
        teaches nothing)."""
        pixels, inside = region_pixels(frame, box, self.surround_scale)
        observed_object, observed_surround = split_histograms(pixels, inside, self.bins)
        if observed_object is None or observed_surround is None:
            return
        if self.object_hist is None or self.surround_hist is None:
            self.object_hist, self.surround_hist = observed_object, observed_surround
        else:
            self.object_hist = (1.0 - self.rate) * self.object_hist + self.rate * observed_object
            self.surround_hist = (1.0 - self.rate) * self.surround_hist + self.rate * observed_surround
        share = float(observed_object[self._target_colours()].sum())
        self.share_reference = updated_reference(self.share_reference, share, self.reference_rate, self.reference_rate)
        similarity = bhattacharyya(self.object_hist, observed_object)
        self.similarity_reference = updated_reference(self.similarity_reference, similarity, self.reference_rate,
                                                       self.reference_rate)

    def relative_match(self, frame: np.ndarray, box: Box) -> float:
        """The larger of box's similarity and share of the target's colours in `frame`, each over its
        reference (1: as the tracked target; 0 for a box outside the frame; inf before anything was
        learnt, or with a zero reference: nothing to judge with)."""
        if self.object_hist is None or not self.share_reference or not self.similarity_reference:
            return math.inf
        pixels, _ = region_pixels(frame, box)
        observed = histogram(pixels, self.bins)
        if observed is None:
            return 0.0
        share = float(observed[self._target_colours()].sum()) / self.share_reference
        return max(share, bhattacharyya(self.object_hist, observed) / self.similarity_reference)

    def _target_colours(self) -> np.ndarray:
        assert self.object_hist is not None and self.surround_hist is not None
        return target_colours(self.object_hist, self.surround_hist, self.surround_prior)


ANCHOR_ODDS = 2.0  # a colour is the target's if twice as frequent in its central part as around it
HUES, SATURATIONS, GREYS = 12, 2, 4  # the drift check's colour bins: hue x saturation, and grey levels
MIN_SATURATION, MIN_VALUE = 48, 40  # below either (0..255) a pixel's hue is noise: it counts as a grey
DARK_BIN = HUES * SATURATIONS  # the darkest grey level (value < 64): shadow, never a colour of the target's
MIN_LIT = 0.05  # a box with fewer pixels outside DARK_BIN shows no colours


def hue_histogram(pixels: np.ndarray) -> np.ndarray | None:
    """Histogram (HUES * SATURATIONS + GREYS,) of BGR uint8 pixels (N, 3) over hue x saturation, greys apart
    by value, summing to 1; a grey frame's pixels (N,) fill the grey bins alone (None for no pixels). Hue
    ignores brightness: a target driving into shade keeps its bins, which fixed RGB levels do not."""
    if len(pixels) == 0:
        return None
    if pixels.ndim == 1:
        index = HUES * SATURATIONS + ((pixels.astype(np.int32) * GREYS) >> 8)
        return np.bincount(index, minlength=HUES * SATURATIONS + GREYS).astype(np.float64) / len(pixels)
    # One row of N pixels: OpenCV converts a row at a time, and N rows of one pixel cost it more than the rest of
    # this function.
    hsv = cv2.cvtColor(np.ascontiguousarray(pixels, dtype=np.uint8).reshape(1, -1, 3), cv2.COLOR_BGR2HSV)
    hue, sat, val = (hsv[0, :, k].astype(np.int32) for k in range(3))
    chromatic = (sat >= MIN_SATURATION) & (val >= MIN_VALUE)
    sat_bin = np.minimum((sat - MIN_SATURATION) * SATURATIONS // (256 - MIN_SATURATION), SATURATIONS - 1)
    index = np.where(chromatic, (hue * HUES // 180) * SATURATIONS + sat_bin,
                     HUES * SATURATIONS + ((val * GREYS) >> 8))
    counts = np.bincount(index, minlength=HUES * SATURATIONS + GREYS).astype(np.float64)
    return counts / counts.sum()


def lit_share(hist: np.ndarray, colours: np.ndarray) -> float:
    """The share of `colours` among a hue_histogram's pixels outside DARK_BIN (0 with under MIN_LIT of them)."""
    lit = 1.0 - float(hist[DARK_BIN])
    return float(hist[colours].sum()) / lit if lit >= MIN_LIT else 0.0


def inner_box(box: Box, fraction: float) -> Box:
    """The central part of `box` (x, y, w, h px): `fraction` of its width and height, same centre."""
    x, y, w, h = box
    return x + w * (1.0 - fraction) / 2.0, y + h * (1.0 - fraction) / 2.0, w * fraction, h * fraction


class AnchorColours:
    """The target's colours as the operator selected it, never updated: the drift check (docs/method.md).

    Colours (hue_histogram's bins) at least ANCHOR_ODDS times as frequent in the selected box's central
    part (`inner` of its width and height) as in everything else out to the box enlarged `surround_scale`
    times per side, the box's corners included (a loose box's background is there). DARK_BIN is never one.
    `share(frame, box)`: the share of a box's central part in them, among its pixels outside DARK_BIN, over
    the selected box's (1: as at selection). Under `min_reference` at selection the target has no colours
    of its own: `usable` is False and every share is inf. ColourModel learns what the track follows, a
    background it slid onto included; this model cannot."""

    def __init__(self, frame: np.ndarray, box: Box, surround_scale: float, inner: float, min_reference: float) -> None:
        self.inner = inner
        scale = surround_scale / inner  # the central part enlarged out to the box's surround
        pixels, central = region_pixels(frame, inner_box(box, inner), scale)
        object_hist, surround_hist = hue_histogram(pixels[central]), hue_histogram(pixels[~central])
        self.colours: np.ndarray | None = None
        self.reference = 0.0
        if object_hist is not None and surround_hist is not None:
            # Twice as frequent in the central part as around it, not P(target | c) > 1/2 with the areas as
            # priors: that refuses the target's own colour when the box is a part of it (a car's middle)
            # and the rest of it lies in the surround.
            self.colours = target_colours(object_hist, surround_hist, ANCHOR_ODDS)
            self.colours[DARK_BIN] = False
            self.reference = lit_share(object_hist, self.colours)
        self.usable = self.colours is not None and self.reference >= min_reference

    def share(self, frame: np.ndarray, box: Box) -> float:
        """The share of box's central part in the target's selected colours over the selected box's
        (0 for a box outside the frame; inf when not usable)."""
        if not self.usable:
            return math.inf
        assert self.colours is not None
        pixels, _ = region_pixels(frame, inner_box(box, self.inner))
        observed = hue_histogram(pixels)
        return 0.0 if observed is None else lit_share(observed, self.colours) / self.reference
