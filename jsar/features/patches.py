"""Image patches: crop a region (possibly partly or wholly outside the image) and resample it.

Pixel k covers [k, k+1); a region of centre (cx, cy) and size (w, h) px covers [cx - w/2, cx + w/2) x
[cy - h/2, cy + h/2); arrays are (rows, cols[, 3]). Per axis, from the scale s = region size / output size:
shrinking (s > 1), the exact mean over each output pixel's footprint (cv2.INTER_AREA); enlarging, linear
interpolation at its centre (cv2.INTER_LINEAR's positions). The border is replicated by clamping source
indices, so no padded copy is made however far outside the region lies. uint8 results are rounded half up,
equal to cv2.resize on whole-pixel regions inside the image up to OpenCV's fixed-point weights.
The compiled kernel (jsar/features/_kernels.c) runs `sample_patch`, `sample_patches` and `resample_regions`;
`axis_weights` + `resample_regions_reference` are the numpy specification it is tested against, and
`resample_reference_loops` (the kernel's earlier loops) the numbers it must give to the bit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsar.features._native import kernels as _kernels


@dataclass(frozen=True)
class AxisWeights:
    """Sparse 1-D resampling operator: out[..., j] = sum_k weight[..., j, k] * src[index[..., j, k]]."""

    index: np.ndarray  # int32 (..., n_out, taps), source indices already clamped into [0, n_src)
    weight: np.ndarray  # float32 (..., n_out, taps), each row sums to 1


def axis_weights(start: np.ndarray, size: np.ndarray, n_out: int, n_src: int) -> AxisWeights:
    """Resampling weights along one axis for regions [start, start+size) (arrays (...,), pixels) -> n_out samples.

    Footprint of sample j: centred at start + (j + 0.5) * s with width max(s, 1), s = size / n_out;
    source pixel q covers [q, q+1) and indices outside [0, n_src) are clamped (border replicated).
    """
    start = np.asarray(start, dtype=np.float64)
    size = np.asarray(size, dtype=np.float64)
    step = size / n_out
    width = np.maximum(step, 1.0)
    centre = start[..., None] + (np.arange(n_out) + 0.5) * step[..., None]
    lo = centre - 0.5 * width[..., None]
    hi = centre + 0.5 * width[..., None]
    # Pixel 0 stands for everything left of the image and pixel n_src - 1 for everything right of
    # it (border replication), so a footprint never needs more taps than the image has pixels.
    first = np.clip(np.floor(lo), 0, n_src - 1)
    last = np.clip(np.ceil(hi) - 1, 0, n_src - 1)
    taps = int(np.max(last - first)) + 1
    pixel = first[..., None] + np.arange(taps)  # (..., n_out, taps)
    cell_lo = np.where(pixel <= 0, -np.inf, pixel)
    cell_hi = np.where(pixel >= n_src - 1, np.inf, pixel + 1.0)
    cell_lo = np.where(pixel > last[..., None], np.inf, cell_lo)  # padding taps get no weight
    overlap = np.minimum(hi[..., None], cell_hi) - np.maximum(lo[..., None], cell_lo)
    weight = np.clip(overlap, 0.0, None) / (hi - lo)[..., None]
    index = np.minimum(pixel, n_src - 1).astype(np.int32)
    return AxisWeights(index=index, weight=weight.astype(np.float32))


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"image must be HxW or HxWx3, got shape {image.shape}")
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"image is empty: shape {image.shape}")


def _check_out(out_wh: tuple[int, int]) -> tuple[int, int]:
    try:
        out_w, out_h = (int(v) for v in out_wh)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"out_wh must be two integers (out_w, out_h), got {out_wh!r}") from exc
    if out_w < 1 or out_h < 1:
        raise ValueError(f"out_wh must be positive, got {out_wh!r}")
    return out_w, out_h


def _check_regions(centre_xy: object, sizes_wh: object) -> tuple[np.ndarray, np.ndarray]:
    centre = np.asarray(centre_xy, dtype=np.float64)
    sizes = np.asarray(sizes_wh, dtype=np.float64)
    if centre.shape != (2,):
        raise ValueError(f"centre_xy must be two numbers (cx, cy), got shape {centre.shape}")
    if sizes.ndim != 2 or sizes.shape[1] != 2 or sizes.shape[0] < 1:
        raise ValueError(f"sizes_wh must be an (N, 2) array of (w, h), got shape {sizes.shape}")
    if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(sizes))):
        raise ValueError("centre_xy and sizes_wh must be finite")
    if np.any(sizes <= 0):
        raise ValueError(f"region sizes must be positive, got min {sizes.min()}")
    return centre, sizes


def _validated(image: np.ndarray, centre_xy: object, sizes_wh: object, out_wh: tuple[int, int]):
    _check_image(image)
    out_w, out_h = _check_out(out_wh)
    centre, sizes = _check_regions(centre_xy, sizes_wh)
    return centre, sizes, out_w, out_h


def _resample_native(image: np.ndarray, centre_xy: object, sizes_wh: object, out_wh: tuple[int, int],
                     dtype: type, kernel=_kernels.resample) -> np.ndarray:
    centre, sizes, out_w, out_h = _validated(image, centre_xy, sizes_wh, out_wh)
    if image.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got dtype {image.dtype}")
    src = np.ascontiguousarray(image)
    height, width = src.shape[:2]
    channels = 1 if src.ndim == 2 else src.shape[2]
    out = np.empty((sizes.shape[0], out_h, out_w) + image.shape[2:], dtype)
    kernel(src, height, width, channels, float(centre[0]), float(centre[1]), np.ascontiguousarray(sizes), sizes.shape[0],
           out_w, out_h, out, dtype == np.uint8)
    return out


def resample_reference_loops(image: np.ndarray, centre_xy: object, sizes_wh: object, out_wh: tuple[int, int],
                             dtype: type = np.uint8) -> np.ndarray:
    """`sample_patches` (uint8) or `resample_regions` (float32) through the compiled kernel's loops of abi 5
    (`resample_reference`): the numbers they must give to the bit (their faster loops are tested against these)."""
    return _resample_native(image, centre_xy, sizes_wh, out_wh, dtype, _kernels.resample_reference)


def resample_regions(image: np.ndarray, centre_xy: object, sizes_wh: object, out_wh: tuple[int, int]) -> np.ndarray:
    """Float32 (N, out_h, out_w[, C]) resampling of N regions sharing one centre (uint8 image); see module docstring."""
    return _resample_native(image, centre_xy, sizes_wh, out_wh, np.float32)


def resample_regions_reference(image: np.ndarray, centre_xy: object, sizes_wh: object,
                               out_wh: tuple[int, int]) -> np.ndarray:
    """numpy reference of `resample_regions` (slow, any real dtype): the specification the tests check against."""
    centre, sizes, out_w, out_h = _validated(image, centre_xy, sizes_wh, out_wh)
    height, width = image.shape[:2]
    wx = axis_weights(centre[0] - 0.5 * sizes[:, 0], sizes[:, 0], out_w, width)
    wy = axis_weights(centre[1] - 0.5 * sizes[:, 1], sizes[:, 1], out_h, height)
    src = image.astype(np.float32, copy=False)
    n = wy.index.shape[0]
    extra = (1,) * (src.ndim - 1)
    rows = (src[wy.index] * wy.weight.reshape(wy.weight.shape + extra)).sum(axis=2)  # (N, out_h, W[, C])
    batch = np.arange(n)[:, None, None, None]
    line = np.arange(rows.shape[1])[None, :, None, None]
    cols = rows[batch, line, wx.index[:, None, :, :]]  # (N, out_h, out_w, tx[, C])
    weight = wx.weight[:, None, :, :].reshape((n, 1) + wx.weight.shape[1:] + extra[1:])
    return (cols * weight).sum(axis=3)


def sample_patches(image: np.ndarray, centre_xy: object, sizes_wh: object, out_wh: tuple[int, int]) -> np.ndarray:
    """uint8 (N, out_h, out_w[, 3]): N regions of sizes sizes_wh (N, 2) pixels centred at centre_xy, resampled."""
    return _resample_native(image, centre_xy, sizes_wh, out_wh, np.uint8)


def sample_patch(image: np.ndarray, centre_xy: object, size_wh: object, out_wh: tuple[int, int]) -> np.ndarray:
    """uint8 (out_h, out_w[, 3]): the region of size size_wh (w, h pixels) centred at centre_xy (x, y), resampled."""
    size = np.asarray(size_wh, dtype=np.float64)
    if size.shape != (2,):
        raise ValueError(f"size_wh must be two numbers (w, h), got shape {size.shape}")
    return sample_patches(image, centre_xy, size[None, :], out_wh)[0]
