"""The verifier: a learnt appearance check of re-detection candidates (VerifyParams).

It compares embeddings (unit vectors from an ImageNet network, jsar.learnt) with two memories:
- the target's: the selection's embedding, kept for good, and those of a few recent reliable frames
  (each within `anchor_similarity` of the selection's);
- the look-alikes': windows around the tracked target on reliable frames (TLD's negative expert) and
  candidates the verifier refused while lost.
A candidate's similarity to a memory is its largest cosine there; it is "target" when its target
similarity reaches `min_similarity` and beats its look-alike similarity by `margin` (DaSiamRPN's
distractor-aware score as a margin), "other" when it falls under `reject_similarity` (and, with
`reject_nearer_other`, a look-alike is at least as near), else "unsure".
Conventions: boxes (x, y, w, h) px; embeddings (N, D) float32 rows of unit length.
"""
from __future__ import annotations

import collections
import concurrent.futures
import enum
import functools
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from jsar.api import Box
from jsar.redetect.params import VerifyParams


class Embedder(Protocol):
    """What the verifier needs of a network: unit-length embeddings of boxes in a frame."""

    def embed(self, frame: np.ndarray, boxes_xywh: np.ndarray) -> np.ndarray:
        """(N, D) float32 unit rows for (N, 4) boxes (x, y, w, h px) of a uint8 BGR frame."""
        ...


class Verdict(enum.Enum):
    """The verifier's answer on one candidate."""

    TARGET = "target"
    UNSURE = "unsure"
    OTHER = "other"


@dataclass(frozen=True)
class Look:
    """One candidate's similarities (cosine, -1..1) to the target memory and to the look-alike memory
    (-1 while it is empty), the verdict they give, and its cosine to the selection's embedding alone."""

    target: float
    other: float
    verdict: Verdict
    selection: float = 1.0


def max_cosine(rows: np.ndarray, memory: np.ndarray) -> np.ndarray:
    """(N,) largest cosine of each unit row (N, D) with the unit rows of memory (M, D); -1 where M = 0."""
    if len(memory) == 0:
        return np.full(len(rows), -1.0, np.float32)
    return (rows @ memory.T).max(axis=1)


def ring_boxes(box: Box, distance_sides: float, count: int,
               frame_wh: tuple[int, int]) -> np.ndarray:
    """(M, 4) boxes of `box`'s size centred `distance_sides` target sides sqrt(w*h) from its centre at
    `count` evenly spaced angles, those whose centre lies inside the frame (x, y, w, h px)."""
    x, y, w, h = box
    side = float(np.sqrt(w * h))
    angles = 2.0 * np.pi * np.arange(count) / max(count, 1)
    cx = x + w / 2.0 + distance_sides * side * np.cos(angles)
    cy = y + h / 2.0 + distance_sides * side * np.sin(angles)
    inside = (cx >= 0) & (cx < frame_wh[0]) & (cy >= 0) & (cy < frame_wh[1])
    return np.column_stack([cx - w / 2.0, cy - h / 2.0, np.full(len(cx), w), np.full(len(cx), h)])[inside]


class AppearanceMemory:
    """The target's and the look-alikes' embeddings; `judge` gives a candidate's Look."""

    def __init__(self, params: VerifyParams, first: np.ndarray) -> None:
        self.params = params
        self.first = np.asarray(first, np.float32).reshape(1, -1)
        self.recent: collections.deque[np.ndarray] = collections.deque(maxlen=max(params.target_slots - 1, 0))
        self.others: collections.deque[np.ndarray] = collections.deque(maxlen=params.other_slots)

    def target_rows(self) -> np.ndarray:
        """(K, D) the target memory: the selection's embedding, then the recent ones."""
        return np.vstack([self.first, *self.recent]) if self.recent else self.first

    def other_rows(self) -> np.ndarray:
        """(M, D) the look-alike memory (M may be 0)."""
        return np.vstack(list(self.others)) if self.others else np.empty((0, self.first.shape[1]), np.float32)

    def learn_target(self, embedding: np.ndarray) -> bool:
        """Add one reliable frame's target embedding (D,) (the oldest recent one goes) unless it would be
        judged another object or lies under anchor_similarity from the selection's; whether it was added.

        A box that slid must not teach the memory its new look. Judged against the recent looks alone, a slow
        slide passes (each look near the last learnt one) and the memory follows it; the selection's bound
        keeps the memory where the operator put it."""
        row = np.asarray(embedding, np.float32).reshape(-1)
        if not self.recent.maxlen or float(row @ self.first[0]) < self.params.anchor_similarity:
            return False
        if self.judge(row[None])[0].verdict is Verdict.OTHER:
            return False
        self.recent.append(row)
        return True

    def learn_others(self, embeddings: np.ndarray) -> None:
        """Add look-alike embeddings (M, D), except those within min_similarity of the target memory: a window
        that overlaps the target, or the target itself refused, must not teach the target away."""
        rows = np.asarray(embeddings, np.float32).reshape(-1, self.first.shape[1])
        if len(rows) == 0:
            return
        close = max_cosine(rows, self.target_rows()) >= self.params.min_similarity
        for row in rows[~close]:
            self.others.append(row)

    def judge(self, embeddings: np.ndarray) -> list[Look]:
        """The Look of each candidate embedding (N, D)."""
        rows = np.asarray(embeddings, np.float32).reshape(-1, self.first.shape[1])
        target = max_cosine(rows, self.target_rows())
        other = max_cosine(rows, self.other_rows())
        selection = rows @ self.first[0]
        looks = []
        for t, o, first in zip(target.tolist(), other.tolist(), selection.tolist()):
            if t >= self.params.min_similarity and t - o >= self.params.margin:
                verdict = Verdict.TARGET
            elif t < self.params.reject_similarity and (o >= t or not self.params.reject_nearer_other):
                verdict = Verdict.OTHER
            else:
                verdict = Verdict.UNSURE
            looks.append(Look(t, o, verdict, first))
        return looks


def map_peaks(score: np.ndarray, count: int, min_value: float, spacing: float) -> list[tuple[int, int, float]]:
    """Up to `count` (row, col, value) maxima of a score map (h, w), best first, each >= min_value and more
    than `spacing` cells from every better one kept (greedy non-maximum suppression)."""
    order = np.argsort(score, axis=None)[::-1]
    kept: list[tuple[int, int, float]] = []
    for flat in order:
        value = float(score.flat[flat])
        if value < min_value or len(kept) == count:
            break
        r, c = divmod(int(flat), score.shape[1])
        if all((r - kr) ** 2 + (c - kc) ** 2 > spacing ** 2 for kr, kc, _ in kept):
            kept.append((r, c, value))
    return kept


def as_bgr(frame: np.ndarray) -> np.ndarray:
    """A uint8 frame as BGR (H, W, 3): a grey frame's level in all three channels (the network wants colour)."""
    return np.repeat(frame[:, :, None], 3, axis=2) if frame.ndim == 2 else frame


class NetworkEmbedder:
    """The verifier's Embedder and the whole-gate search's maps: jsar.learnt's MobileNetV2 features."""

    def __init__(self, cut: int = 16) -> None:
        from jsar.learnt.mobilenet import FeatureNet  # the weights load here, not on importing the tracker
        self.net = FeatureNet(cut=cut)

    def embed(self, frame: np.ndarray, boxes_xywh: np.ndarray) -> np.ndarray:
        """(N, D) float32 unit rows for (N, 4) boxes (x, y, w, h px) of a uint8 BGR frame."""
        from jsar.learnt.embedding import embed
        return embed(self.net, as_bgr(frame), boxes_xywh)

    def template(self, frame: np.ndarray, box_xywh: Box, cells: int
                 ) -> tuple[np.ndarray, float]:
        """The target's feature cells (C, th, tw) with its side sqrt(w*h) `cells` cells across, and that scale
        (resized px per frame px)."""
        from jsar.learnt.embedding import target_template
        scale = cells * self.net.stride / float(np.sqrt(box_xywh[2] * box_xywh[3]))
        return target_template(self.net, as_bgr(frame), box_xywh, scale), scale

    def gate_peaks(self, frame: np.ndarray, region_xywh: Box, scale: float,
                   template: np.ndarray, count: int, min_value: float) -> list[tuple[float, float, float]]:
        """Up to `count` (x px, y px, cosine) box centres where the template matches best in the region
        (x, y, w, h px) resized by `scale`, one forward pass, best first, a template apart."""
        from jsar.learnt.embedding import feature_map, match_map, peak_to_frame
        fmap = feature_map(self.net, as_bgr(frame), region_xywh, scale)
        if fmap.shape[1] < template.shape[1] or fmap.shape[2] < template.shape[2]:
            return []
        score = match_map(fmap, template)
        spacing = float(max(template.shape[1:]))
        return [(*peak_to_frame(r, c, template.shape, region_xywh, scale, self.net.stride), v)
                for r, c, v in map_peaks(score, count, min_value, spacing)]


@functools.lru_cache(maxsize=1)
def shared_embedder() -> NetworkEmbedder:
    """One network per process, shared by every tracker (it holds no per-target state)."""
    return NetworkEmbedder()


class DeferredEmbeddings:
    """The embeddings of boxes of one frame, started now and used later (`rows()` waits for them).

    With `worker` (a one-thread executor) they are computed there meanwhile, on another core; without, on
    the first `rows()`. Either way the rows are the same: the frame is copied (its owner may reuse it)."""

    def __init__(self, embedder: Embedder, frame: np.ndarray, boxes_xywh: np.ndarray,
                 worker: concurrent.futures.Executor | None = None) -> None:
        frame, boxes = frame.copy(), np.array(boxes_xywh, dtype=np.float64)
        self._future = worker.submit(embedder.embed, frame, boxes) if worker is not None else None
        self._compute: tuple[Embedder, np.ndarray, np.ndarray] | None = (embedder, frame, boxes) if worker is None else None
        self._rows: np.ndarray | None = None

    def rows(self) -> np.ndarray:
        """(N, D) float32 unit rows of the boxes, computed once."""
        if self._rows is None:
            if self._future is not None:
                self._rows = self._future.result()
            else:
                assert self._compute is not None
                embedder, frame, boxes = self._compute
                self._rows = embedder.embed(frame, boxes)
            self._compute = self._future = None  # the frame copy goes
        return self._rows
