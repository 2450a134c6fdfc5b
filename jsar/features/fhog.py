"""Felzenszwalb HOG (fHOG, PAMI 2010): 31 channels per cell = 18 signed + 9 unsigned orientations + 4 texture.

Input grey HxW or colour HxWx3 on 0..255 (colour: per pixel the channel with the largest gradient). Gradients:
central differences, one-sided at the border (cv2.Sobel ksize=1, BORDER_REPLICATE). Orientation atan2(gy, gx)
in image coordinates (x right, y down): 18 signed bins centred at k * 20 degrees, each pixel's magnitude split
linearly between the two nearest; each pixel split bilinearly between the four nearest cell centres
((c + 0.5) * cell px), output (H // cell, W // cell). Every cell normalised by its four 2x2-cell blocks
(1 / sqrt(block energy + EPS)) and clipped at 0.2; EPS is on this unscaled histogram scale, so it matters only
on flat regions. The compiled kernel (jsar/features/_kernels.c) runs `fhog` / `fhog_batch`; the numpy functions
below are the specification it is tested against (agreement to 2e-5), and `fhog_batch_reference_loops` (the
kernel's earlier loops) the numbers it must give to the bit.
"""
from __future__ import annotations

import cv2
import numpy as np

from jsar.features._native import kernels as _kernels

N_SIGNED = 18
N_UNSIGNED = 9
N_CHANNELS = 31
CLIP = 0.2
EPS = 1e-4
TEXTURE_SCALE = 0.2357


def gradients(images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gx, gy) float32 (N, H, W) of a stack (N, H, W[, C]); colour keeps the strongest channel per pixel."""
    n, h, w = images.shape[:3]
    channels = 1 if images.ndim == 3 else images.shape[3]
    stack = np.ascontiguousarray(images, dtype=np.float32).reshape((n * h, w) + images.shape[3:])
    gx = cv2.Sobel(stack, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(stack, cv2.CV_32F, 0, 1, ksize=1, borderType=cv2.BORDER_REPLICATE)
    gx = gx.reshape(n, h, w, channels)
    gy = gy.reshape(n, h, w, channels)
    # The stack is one tall image: rows 0 and H-1 of each patch must not see the neighbouring patch.
    stack4 = stack.reshape(n, h, w, channels)
    if h > 1:
        gy[:, 0] = stack4[:, 1] - stack4[:, 0]
        gy[:, -1] = stack4[:, -1] - stack4[:, -2]
    else:
        gy[:, 0] = 0.0
    if channels == 1:
        return gx[..., 0], gy[..., 0]
    energy = gx * gx + gy * gy
    best = np.argmax(energy, axis=3)[..., None]
    return np.take_along_axis(gx, best, 3)[..., 0], np.take_along_axis(gy, best, 3)[..., 0]


def cell_weights(n_pixels: int, cell: int) -> np.ndarray:
    """float32 (n_pixels // cell, n_pixels): bilinear weight of pixel p (centre p + 0.5) on cell c (centre (c + 0.5) * cell)."""
    n_cells = n_pixels // cell
    pixel_pos = (np.arange(n_pixels) + 0.5) / cell - 0.5  # pixel centre in cell units
    dist = np.abs(pixel_pos[None, :] - np.arange(n_cells)[:, None])
    weights = np.clip(1.0 - dist, 0.0, None)
    weights[:, n_cells * cell:] = 0.0  # pixels beyond the last whole cell are ignored
    return weights.astype(np.float32)


def orientation_histograms(gx: np.ndarray, gy: np.ndarray, cell: int) -> np.ndarray:
    """float32 (N, H//cell, W//cell, 18) signed orientation histograms of gradients (N, H, W); see module docstring."""
    n, h, w = gx.shape
    mag = np.hypot(gx, gy).astype(np.float32)
    ang = np.mod(np.arctan2(gy.astype(np.float64), gx), 2 * np.pi)  # radians in [0, 2pi)
    pos = (ang.reshape(-1) * (N_SIGNED / (2 * np.pi))).astype(np.float32)
    low = np.floor(pos)
    frac = pos - low
    low = low.astype(np.int64) % N_SIGNED
    high = (low + 1) % N_SIGNED
    mag = mag.reshape(-1)
    dense = np.zeros((n * h * w, N_SIGNED), np.float32)
    rows = np.arange(n * h * w)
    dense[rows, low] = mag * (1.0 - frac)
    dense[rows, high] = mag * frac  # high != low, so these never overwrite the first assignment
    dense = dense.reshape(n, h, w * N_SIGNED)
    sy = cell_weights(h, cell)
    sx = cell_weights(w, cell)
    rows_binned = np.matmul(sy, dense)  # (N, hc, W*18)
    rows_binned = rows_binned.reshape(n * sy.shape[0], w, N_SIGNED)
    return np.matmul(sx, rows_binned).reshape(n, sy.shape[0], sx.shape[0], N_SIGNED)


def block_factors(hist: np.ndarray, eps: float = EPS) -> np.ndarray:
    """float32 (4, N, hc, wc): 1/sqrt(eps + energy of each of the four 2x2-cell blocks around every cell)."""
    unsigned = hist[..., :N_UNSIGNED] + hist[..., N_UNSIGNED:]
    energy = np.einsum("...o,...o->...", unsigned, unsigned)
    padded = np.pad(energy, ((0, 0), (1, 1), (1, 1)), mode="edge")
    # 2x2 block sums at every corner of the padded grid: block (i, j) covers cells i-1..i, j-1..j.
    blocks = padded[:, :-1, :-1] + padded[:, 1:, :-1] + padded[:, :-1, 1:] + padded[:, 1:, 1:]
    hc, wc = energy.shape[1:]
    corners = [blocks[:, dy:dy + hc, dx:dx + wc] for dy in (0, 1) for dx in (0, 1)]
    return (1.0 / np.sqrt(np.stack(corners) + np.float32(eps))).astype(np.float32)


def clipped_normalised(hist: np.ndarray, eps: float = EPS) -> np.ndarray:
    """float32 (4, N, hc, wc, 27): min(h * n_k, 0.2) for the 18 signed + 9 unsigned histograms, per block k."""
    unsigned = hist[..., :N_UNSIGNED] + hist[..., N_UNSIGNED:]
    both = np.concatenate([hist, unsigned], axis=-1)
    factors = block_factors(hist, eps)
    return np.minimum(both[None] * factors[..., None], np.float32(CLIP))


def features_from_histograms(hist: np.ndarray, eps: float = EPS) -> np.ndarray:
    """float32 (N, hc, wc, 31) fHOG channels from signed histograms (N, hc, wc, 18)."""
    clipped = clipped_normalised(hist, eps)
    out = np.empty(hist.shape[:3] + (N_CHANNELS,), np.float32)
    out[..., :27] = 0.5 * clipped.sum(axis=0)
    out[..., 27:] = np.moveaxis(TEXTURE_SCALE * clipped[..., :N_SIGNED].sum(axis=-1), 0, -1)
    return out


def _check_images(images: np.ndarray, batched: bool, cell: int) -> np.ndarray:
    if not isinstance(images, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(images).__name__}")
    if not isinstance(cell, (int, np.integer)) or cell < 1:
        raise ValueError(f"cell must be a positive integer, got {cell!r}")
    base = 1 if batched else 0
    if images.ndim not in (base + 2, base + 3) or (images.ndim == base + 3 and images.shape[-1] != 3):
        shape_text = "(N, H, W) or (N, H, W, 3)" if batched else "HxW or HxWx3"
        raise ValueError(f"image must be {shape_text}, got shape {images.shape}")
    if images.shape[base] < cell or images.shape[base + 1] < cell:
        raise ValueError(f"image {images.shape} is smaller than one {cell}x{cell} cell")
    if not np.issubdtype(images.dtype, np.number) or np.issubdtype(images.dtype, np.complexfloating):
        raise ValueError(f"image must be real-valued, got dtype {images.dtype}")
    if np.issubdtype(images.dtype, np.floating) and not np.all(np.isfinite(images)):
        raise ValueError("image holds NaN or infinite values")
    if batched and images.shape[0] < 1:
        raise ValueError("images must hold at least one image")
    return images


def fhog_batch_reference(images: np.ndarray, cell: int = 4) -> np.ndarray:
    """numpy reference of `fhog_batch` (slower): the specification the compiled kernel is tested against."""
    _check_images(images, True, cell)
    gx, gy = gradients(images)
    return features_from_histograms(orientation_histograms(gx, gy, cell))


def fhog_batch(images: np.ndarray, cell: int = 4, stack: np.ndarray | None = None, channel: int = 0) -> np.ndarray:
    """float32 (N, H//cell, W//cell, 31) fHOG of N equal-size images (N, H, W[, 3]) on a 0..255 scale.

    With `stack`, a C-contiguous float32 (N, H//cell, W//cell, C) array, the 31 channels are written into
    stack[..., channel:channel + 31] (a feature stack, without a copy) and that view is returned.
    """
    _check_images(images, True, cell)
    if images.dtype == np.uint8:
        src = np.ascontiguousarray(images)
    else:
        src = np.ascontiguousarray(images, dtype=np.float32)
    n, h, w = src.shape[:3]
    channels = 1 if src.ndim == 3 else 3
    if stack is None:
        out = np.empty((n, h // cell, w // cell, N_CHANNELS), np.float32)
        _kernels.fhog(src, n, h, w, channels, src.dtype == np.uint8, int(cell), out)
        return out
    if (stack.dtype != np.float32 or not stack.flags.c_contiguous or stack.shape[:3] != (n, h // cell, w // cell)
            or not 0 <= channel <= stack.shape[3] - N_CHANNELS):
        raise ValueError(f"stack must be C-contiguous float32 ({n}, {h // cell}, {w // cell}, >= channel + 31), "
                         f"got {stack.dtype} {stack.shape} for channel {channel}")
    _kernels.fhog(src, n, h, w, channels, src.dtype == np.uint8, int(cell), stack.reshape(-1)[channel:], stack.shape[3])
    return stack[..., channel:channel + N_CHANNELS]


def fhog_batch_reference_loops(images: np.ndarray, cell: int = 4) -> np.ndarray:
    """`fhog_batch` through the compiled kernel's loops of abi 5 (`fhog_reference`): the numbers `fhog_batch` must
    give to the bit (its faster loops are tested against these)."""
    _check_images(images, True, cell)
    src = np.ascontiguousarray(images) if images.dtype == np.uint8 else np.ascontiguousarray(images, dtype=np.float32)
    n, h, w = src.shape[:3]
    out = np.empty((n, h // cell, w // cell, N_CHANNELS), np.float32)
    _kernels.fhog_reference(src, n, h, w, 1 if src.ndim == 3 else 3, src.dtype == np.uint8, int(cell), out)
    return out


def fhog(image: np.ndarray, cell: int = 4) -> np.ndarray:
    """float32 (H//cell, W//cell, 31) fHOG of one grey HxW or colour HxWx3 image on a 0..255 scale."""
    _check_images(image, False, cell)
    return fhog_batch(image[None], cell)[0]
