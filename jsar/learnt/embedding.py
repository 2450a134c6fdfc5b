"""Appearance embeddings and dense match maps from MobileNetV2's early features (jsar.learnt.mobilenet).

- `embed`: per box a vector: the box, enlarged by `context` of its size per side, resized to a fixed
  square input; the feature cells covering the box pooled (mean, grid of means, or both) and L2-normalised.
- `feature_map` / `target_template` / `match_map`: one forward pass over a search region (resized by
  `scale`), the target's feature cells as a template, their cosine with every window as a dense score
  map; `peak_to_frame` maps a map position back to the box centre in frame pixels.
Conventions: frames uint8 HxWx3 BGR; boxes and regions (x, y, w, h) frame px, (x, y) the top-left corner;
feature maps (C, rows, cols), cell (i, j) at stride s centred on the resized region's pixel (i*s, j*s)
(MobileNetV2's stride-2 convs keep pixel 0 as cell 0's centre).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from jsar.api import Box
from jsar.learnt.mobilenet import FeatureNet

POOLINGS = ("mean", "grid", "mean+grid")


def crop_resized(frame_bgr: np.ndarray, region_xywh: Box, out_wh: tuple[int, int]) -> np.ndarray:
    """(out_h, out_w, 3) uint8: the region (x, y, w, h px; may leave the frame, edges replicated) resized."""
    x, y, w, h = (float(v) for v in region_xywh)
    out_w, out_h = out_wh
    if w <= 0 or h <= 0 or out_w <= 0 or out_h <= 0:
        raise ValueError(f"region {region_xywh} and output {out_wh} must have positive sizes")
    sx, sy = out_w / w, out_h / h
    if sx >= 0.5 and sy >= 0.5:
        # mild or no shrink: one sub-pixel warp; output pixel u samples frame x + (u + 0.5) / sx - 0.5
        m = np.array([[sx, 0.0, sx * (0.5 - x) - 0.5], [0.0, sy, sy * (0.5 - y) - 0.5]])
        return cv2.warpAffine(frame_bgr, m, (out_w, out_h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # strong shrink: area averaging (a bilinear warp would alias), on the whole-pixel crop
    x0, y0 = int(math.floor(x + 0.5)), int(math.floor(y + 0.5))
    x1, y1 = max(x0 + 1, int(math.floor(x + w + 0.5))), max(y0 + 1, int(math.floor(y + h + 0.5)))
    fh, fw = frame_bgr.shape[:2]
    # the part inside the frame (at least its nearest edge pixel), then the rest by edge replication
    cx0, cx1 = min(max(x0, 0), fw - 1), max(min(x1, fw), 1)
    cy0, cy1 = min(max(y0, 0), fh - 1), max(min(y1, fh), 1)
    cx1, cy1 = max(cx1, cx0 + 1), max(cy1, cy0 + 1)
    crop = frame_bgr[cy0:cy1, cx0:cx1]
    pad = (max(0, cy0 - y0), max(0, y1 - cy1), max(0, cx0 - x0), max(0, x1 - cx1))
    if any(pad):
        crop = cv2.copyMakeBorder(crop, *pad, borderType=cv2.BORDER_REPLICATE)
    return cv2.resize(crop, (out_w, out_h), interpolation=cv2.INTER_AREA)


def crop_windows(frame_bgr: np.ndarray, boxes_xywh: np.ndarray, context: float, size: int) -> np.ndarray:
    """(N, size, size, 3) uint8: each box enlarged by `context` x its size per side, resized to size x size."""
    boxes = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
    out = np.empty((len(boxes), size, size, 3), dtype=np.uint8)
    for k, (x, y, w, h) in enumerate(boxes):
        out[k] = crop_resized(frame_bgr, (x - context * w, y - context * h, w * (1 + 2 * context),
                                          h * (1 + 2 * context)), (size, size))
    return out


def box_cells(cells: int, context: float) -> tuple[int, int]:
    """[first, stop) of the feature cells along one axis of a crop that cover the box (not its context)."""
    margin = int(round(cells * context / (1 + 2 * context)))
    return margin, max(margin + 1, cells - margin)


def pool(fmaps: np.ndarray, pooling: str = "mean", grid: int = 2) -> np.ndarray:
    """(N, C, h, w) -> (N, D): mean (D = C), grid x grid cell means (D = grid^2 C) or both, L2-normalised."""
    if pooling not in POOLINGS:
        raise ValueError(f"pooling must be one of {POOLINGS}, got {pooling!r}")
    n, c, h, w = fmaps.shape
    parts = []
    if "mean" in pooling.split("+"):
        parts.append(fmaps.mean(axis=(2, 3)))
    if "grid" in pooling.split("+"):
        rows = np.linspace(0, h, grid + 1).round().astype(int)
        cols = np.linspace(0, w, grid + 1).round().astype(int)
        for i in range(grid):
            for j in range(grid):
                cell = fmaps[:, :, rows[i]:max(rows[i + 1], rows[i] + 1), cols[j]:max(cols[j + 1], cols[j] + 1)]
                parts.append(cell.mean(axis=(2, 3)))
    vec = np.concatenate(parts, axis=1).astype(np.float32)
    return vec / np.maximum(np.linalg.norm(vec, axis=1, keepdims=True), 1e-12)


def embedding_size(net: FeatureNet, pooling: str = "mean", grid: int = 2) -> int:
    """D of `embed`'s vectors: C for the mean, grid^2 C for the grid, (1 + grid^2) C for both."""
    parts = pooling.split("+")
    return net.channels * (("mean" in parts) + ("grid" in parts) * grid * grid)


def embed(net: FeatureNet, frame_bgr: np.ndarray, boxes_xywh: np.ndarray, *, context: float = 0.5,
          size: int = 64, pooling: str = "mean", grid: int = 2) -> np.ndarray:
    """(N, D) float32 L2-normalised embeddings of boxes (N, 4) x, y, w, h px: one batched forward pass."""
    # defaults: the best separation of `python -m bench.learnt --separation` (docs/method.md, "Learnt
    # features"); a grid keeps layout, which a turning target changes more than it tells look-alikes apart
    boxes = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
    if len(boxes) == 0:
        return np.zeros((0, embedding_size(net, pooling, grid)), dtype=np.float32)
    fmaps = net.features_batch(crop_windows(frame_bgr, boxes, context, size))
    r0, r1 = box_cells(fmaps.shape[2], context)
    c0, c1 = box_cells(fmaps.shape[3], context)
    return pool(fmaps[:, :, r0:r1, c0:c1], pooling, grid)


def feature_map(net: FeatureNet, frame_bgr: np.ndarray, region_xywh: Box, scale: float) -> np.ndarray:
    """(C, ceil(round(h*scale)/s), ceil(round(w*scale)/s)) features of the region (x, y, w, h px) resized by scale."""
    _, _, w, h = region_xywh
    out_wh = (max(1, int(round(w * scale))), max(1, int(round(h * scale))))
    return net.features(crop_resized(frame_bgr, region_xywh, out_wh))


def template_cells(box_wh: tuple[float, float], scale: float, stride: int) -> tuple[int, int]:
    """(rows, cols) of a target template: the box size in feature cells at `scale`, at least 1."""
    w, h = box_wh
    return max(1, int(round(h * scale / stride))), max(1, int(round(w * scale / stride)))


def target_template(net: FeatureNet, frame_bgr: np.ndarray, box_xywh: Box, scale: float,
                    margin: int = 2) -> np.ndarray:
    """(C, th, tw) the target's own feature cells at `scale`, centred on the box (margin cells computed
    around it and dropped, so the zero padding at a map's edge does not reach the template)."""
    s = net.stride
    th, tw = template_cells((box_xywh[2], box_xywh[3]), scale, s)
    cx, cy = box_xywh[0] + box_xywh[2] / 2, box_xywh[1] + box_xywh[3] / 2
    # region of whole cells: its resized size is exactly (tw + 2 margin) s by (th + 2 margin) s pixels
    w, h = (tw + 2 * margin) * s / scale, (th + 2 * margin) * s / scale
    fmap = feature_map(net, frame_bgr, (cx - w / 2, cy - h / 2, w, h), scale)
    return np.ascontiguousarray(fmap[:, margin:margin + th, margin:margin + tw])


def match_map(fmap: np.ndarray, template: np.ndarray) -> np.ndarray:
    """(h - th + 1, w - tw + 1) cosine of the template (C, th, tw) with each window of fmap (C, h, w)."""
    c, h, w = fmap.shape
    tc, th, tw = template.shape
    if tc != c or th > h or tw > w:
        raise ValueError(f"template {template.shape} does not fit the feature map {fmap.shape}")
    fmap = np.ascontiguousarray(fmap, dtype=np.float32)
    tmpl = np.ascontiguousarray(template, dtype=np.float32)
    # cross-correlation summed over channels: the channels as one image side by side would mix them at
    # the seams, so each channel is correlated on its own (cv2.matchTemplate, float32)
    corr = np.zeros((h - th + 1, w - tw + 1), dtype=np.float32)
    for k in range(c):
        corr += cv2.matchTemplate(fmap[k], tmpl[k], cv2.TM_CCORR)
    energy = cv2.boxFilter(np.einsum("chw,chw->hw", fmap, fmap), -1, (tw, th), anchor=(0, 0),
                           normalize=False, borderType=cv2.BORDER_CONSTANT)[:h - th + 1, :w - tw + 1]
    norm = np.sqrt(np.maximum(energy, 0.0)) * float(np.linalg.norm(tmpl))
    return corr / np.maximum(norm, 1e-12)


def peak_to_frame(row: float, col: float, template_shape: tuple[int, ...], region_xywh: Box, scale: float,
                  stride: int) -> tuple[float, float]:
    """Frame pixel (x, y) of the box centre for a match-map position (row, col) (sub-cell allowed)."""
    th, tw = template_shape[-2], template_shape[-1]
    # cell j is centred on resized pixel j*s, i.e. frame x + (j*s + 0.5)/scale (edges at whole numbers);
    # target_template's cells are centred (s/2 - 0.5)/scale before the box centre: the two halves cancel
    return (region_xywh[0] + (col + tw / 2) * stride / scale,
            region_xywh[1] + (row + th / 2) * stride / scale)


def best_peak(score: np.ndarray) -> tuple[float, float, float]:
    """(row, col, value) of the match map's maximum, refined to sub-cell by a parabola on each axis."""
    r, c = np.unravel_index(int(np.argmax(score)), score.shape)
    value = float(score[r, c])

    def offset(a: float, b: float, m: float) -> float:
        denom = a - 2 * m + b
        return 0.0 if denom >= 0 else float(np.clip(0.5 * (a - b) / denom, -0.5, 0.5))

    dr = offset(score[r - 1, c], score[r + 1, c], value) if 0 < r < score.shape[0] - 1 else 0.0
    dc = offset(score[r, c - 1], score[r, c + 1], value) if 0 < c < score.shape[1] - 1 else 0.0
    return r + dr, c + dc, value
