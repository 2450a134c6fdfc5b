"""One-pass evaluation metrics (OTB convention), pure functions on (N, 4) box arrays.

Boxes are (x, y, w, h) float pixels, top-left origin, rows aligned frame by frame. A ground-truth
row of NaN means the target is absent: that frame is skipped by every score. A NaN predicted row
(a tracker that gave no box) counts as a miss: infinite centre error, IoU 0.
"""
from __future__ import annotations

import numpy as np

PRECISION_THRESHOLDS_PX = np.arange(0, 51, dtype=np.float64)  # 0..50 px, step 1
SUCCESS_THRESHOLDS = np.linspace(0.0, 1.0, 21)  # IoU 0..1, step 0.05
PRECISION_AT_PX = 20.0


def _as_boxes(boxes: np.ndarray, name: str) -> np.ndarray:
    """Validate and return an (N, 4) float64 box array."""
    array = np.asarray(boxes, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 4:
        raise ValueError(f"{name} must be an (N, 4) array of x,y,w,h, got shape {array.shape}")
    return array


def _aligned(predicted: np.ndarray, groundtruth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both arrays validated and of equal length (ValueError otherwise)."""
    pred = _as_boxes(predicted, "predicted boxes")
    gt = _as_boxes(groundtruth, "ground truth")
    if pred.shape[0] != gt.shape[0]:
        raise ValueError(f"{pred.shape[0]} predicted boxes but {gt.shape[0]} ground-truth rows")
    return pred, gt


def visible_mask(groundtruth: np.ndarray) -> np.ndarray:
    """(N,) bool: True where the ground-truth row is a box (not NaN)."""
    gt = _as_boxes(groundtruth, "ground truth")
    return ~np.any(np.isnan(gt), axis=1)


def centres(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) x,y,w,h -> (N, 2) centre (x + w/2, y + h/2) in pixels."""
    b = _as_boxes(boxes, "boxes")
    return b[:, :2] + b[:, 2:] / 2.0


def centre_errors(predicted: np.ndarray, groundtruth: np.ndarray) -> np.ndarray:
    """(N,) Euclidean centre distance in pixels; NaN where gt is absent, inf where pred is NaN."""
    pred, gt = _aligned(predicted, groundtruth)
    errors = np.linalg.norm(centres(pred) - centres(gt), axis=1)
    errors[np.any(np.isnan(pred), axis=1)] = np.inf
    errors[~visible_mask(gt)] = np.nan
    return errors


def ious(predicted: np.ndarray, groundtruth: np.ndarray) -> np.ndarray:
    """(N,) intersection over union of continuous boxes; NaN where gt is absent, 0 where pred is NaN."""
    pred, gt = _aligned(predicted, groundtruth)
    x0 = np.maximum(pred[:, 0], gt[:, 0])
    y0 = np.maximum(pred[:, 1], gt[:, 1])
    x1 = np.minimum(pred[:, 0] + pred[:, 2], gt[:, 0] + gt[:, 2])
    y1 = np.minimum(pred[:, 1] + pred[:, 3], gt[:, 1] + gt[:, 3])
    intersection = np.clip(x1 - x0, 0.0, None) * np.clip(y1 - y0, 0.0, None)
    union = pred[:, 2] * pred[:, 3] + gt[:, 2] * gt[:, 3] - intersection
    with np.errstate(invalid="ignore", divide="ignore"):
        overlap = np.where(union > 0, intersection / union, 0.0)
    overlap[np.any(np.isnan(pred), axis=1)] = 0.0
    overlap[~visible_mask(gt)] = np.nan
    return overlap


def precision_curve(errors: np.ndarray, thresholds: np.ndarray = PRECISION_THRESHOLDS_PX) -> np.ndarray:
    """Share of scored frames with centre error <= each threshold (px); NaN errors skipped.

    Returns NaN everywhere when no frame is scored (the target is never visible).
    """
    scored = np.asarray(errors, dtype=np.float64)
    scored = scored[~np.isnan(scored)]
    if scored.size == 0:
        return np.full(len(thresholds), np.nan)
    return (scored[None, :] <= np.asarray(thresholds)[:, None]).mean(axis=1)


def success_curve(overlaps: np.ndarray, thresholds: np.ndarray = SUCCESS_THRESHOLDS) -> np.ndarray:
    """Share of scored frames with IoU > each threshold (strict, OTB); NaN overlaps skipped."""
    scored = np.asarray(overlaps, dtype=np.float64)
    scored = scored[~np.isnan(scored)]
    if scored.size == 0:
        return np.full(len(thresholds), np.nan)
    return (scored[None, :] > np.asarray(thresholds)[:, None]).mean(axis=1)


def precision_at(errors: np.ndarray, pixels: float = PRECISION_AT_PX) -> float:
    """Share of scored frames with centre error <= `pixels` (precision at 20 px by default)."""
    return float(precision_curve(errors, np.array([pixels]))[0])


def auc(success: np.ndarray) -> float:
    """Area under the success plot = mean of the curve over its evenly spaced thresholds."""
    return float(np.mean(success))


def score(predicted: np.ndarray, groundtruth: np.ndarray) -> dict[str, object]:
    """All one-pass scores for one sequence: precision@20, AUC, curves, frames scored."""
    errors = centre_errors(predicted, groundtruth)
    overlaps = ious(predicted, groundtruth)
    prec = precision_curve(errors)
    succ = success_curve(overlaps)
    return {
        "precision": precision_at(errors),
        "auc": auc(succ),
        "precision_curve": prec,
        "success_curve": succ,
        "frames_scored": int(np.count_nonzero(~np.isnan(errors))),
    }
