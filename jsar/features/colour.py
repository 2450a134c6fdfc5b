"""Colour attributes: a 10-channel per-pixel colour descriptor looked up from a 32768-entry table.

The original's learned colour-names table (van de Weijer et al.) is not available, so `derived_colour_table`
derives one: each RGB bin (row r//8 + 32*(g//8) + 1024*(b//8), the original's indexing) is soft-assigned to the
11 basic colour terms (Berlin & Kay) by its CIELAB distance d_t to a prototype of each, p_t =
softmax_t(-d_t^2 / (2 sigma^2)), and projected onto the Helmert basis of the sum-zero plane (11 -> 10 without
loss; the filters do not change under an orthogonal mixing of channels). sigma = 16, about where two colours
start to get different names, was chosen before measuring (`python -m bench.colour_ab` measures it). An
external .npy table is loaded instead when given (32768 x 11, projected the same way, or 32768 x 10 as is).
"""
from __future__ import annotations

from os import PathLike

import cv2
import numpy as np

COLOUR_TERMS: tuple[str, ...] = (
    "black", "blue", "brown", "grey", "green", "orange", "pink", "purple", "red", "white", "yellow",
)
# One prototype sRGB colour (0..255) per term, in COLOUR_TERMS order: typical focal colours.
PROTOTYPES_RGB: tuple[tuple[int, int, int], ...] = (
    (0, 0, 0),  # black
    (25, 60, 215),  # blue
    (120, 75, 35),  # brown
    (128, 128, 128),  # grey
    (35, 155, 50),  # green
    (245, 130, 20),  # orange
    (245, 150, 190),  # pink
    (125, 45, 155),  # purple
    (210, 25, 30),  # red
    (255, 255, 255),  # white
    (250, 225, 30),  # yellow
)
TABLE_SIZE = 32 * 32 * 32
N_TERMS = len(COLOUR_TERMS)
N_CHANNELS = N_TERMS - 1
DEFAULT_SIGMA = 16.0


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """float32 (..., 3) CIELAB (L in 0..100) of sRGB values (..., 3) on a 0..255 scale."""
    rgb = np.asarray(rgb, dtype=np.float32)
    flat = (rgb.reshape(-1, 1, 3) / 255.0).astype(np.float32)
    return cv2.cvtColor(flat, cv2.COLOR_RGB2Lab).reshape(rgb.shape)


def bin_centres_rgb() -> np.ndarray:
    """float32 (32768, 3) RGB centre of every table row, row = r//8 + 32*(g//8) + 1024*(b//8)."""
    levels = np.arange(32, dtype=np.float32) * 8 + 3.5
    b, g, r = np.meshgrid(levels, levels, levels, indexing="ij")  # r varies fastest
    return np.stack([r.ravel(), g.ravel(), b.ravel()], axis=1)


def colour_term_probabilities(sigma: float = DEFAULT_SIGMA) -> np.ndarray:
    """float32 (32768, 11): soft assignment of every quantised RGB bin to the 11 colour terms (rows sum to 1)."""
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    lab = rgb_to_lab(bin_centres_rgb()).astype(np.float64)
    prototypes = rgb_to_lab(np.array(PROTOTYPES_RGB, np.float32)).astype(np.float64)
    dist2 = np.zeros((lab.shape[0], N_TERMS))
    for axis in range(3):  # per Lab axis: avoids a slow reduction over a length-3 inner axis
        dist2 += (lab[:, axis, None] - prototypes[None, :, axis]) ** 2
    logits = -dist2 / (2.0 * sigma * sigma)
    logits -= logits.max(axis=1, keepdims=True)  # stable softmax
    prob = np.exp(logits)
    prob /= prob.sum(axis=1, keepdims=True)
    return prob.astype(np.float32)


def simplex_basis(n: int = N_TERMS) -> np.ndarray:
    """float64 (n, n-1) Helmert basis: orthonormal columns, each orthogonal to the all-ones vector."""
    basis = np.zeros((n, n - 1))
    for k in range(1, n):
        basis[:k, k - 1] = 1.0
        basis[k, k - 1] = -float(k)
        basis[:, k - 1] /= np.sqrt(k * (k + 1.0))
    return basis


def project_terms(prob: np.ndarray) -> np.ndarray:
    """float32 (..., 10): 11 colour-term values (..., 11) projected on the Helmert basis."""
    return (np.asarray(prob, np.float64) @ simplex_basis(prob.shape[-1])).astype(np.float32)


def derived_colour_table(sigma: float = DEFAULT_SIGMA) -> np.ndarray:
    """float32 (32768, 10): the derived colour-attribute table (see module docstring). Cache it: ~10 ms."""
    return project_terms(colour_term_probabilities(sigma))


def validate_colour_table(table: object) -> np.ndarray:
    """float32 (32768, 10) from a (32768, 10) or (32768, 11) finite float table, else ValueError."""
    if not isinstance(table, np.ndarray):
        raise ValueError(f"colour table must be a numpy array, got {type(table).__name__}")
    if not np.issubdtype(table.dtype, np.floating):
        raise ValueError(f"colour table must be floating point, got dtype {table.dtype}")
    if table.ndim != 2 or table.shape[0] != TABLE_SIZE or table.shape[1] not in (N_CHANNELS, N_TERMS):
        raise ValueError(f"colour table must be {TABLE_SIZE}x{N_CHANNELS} or {TABLE_SIZE}x{N_TERMS}, got {table.shape}")
    if not np.all(np.isfinite(table)):
        raise ValueError("colour table holds NaN or infinite values")
    if table.shape[1] == N_TERMS:
        return project_terms(table)
    return np.ascontiguousarray(table, dtype=np.float32)


def load_colour_table(path: str | PathLike[str]) -> np.ndarray:
    """float32 (32768, 10) from an external .npy table (32768 x 10, or 32768 x 11 projected as documented)."""
    try:
        table = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot read colour table {path}: {exc}") from exc
    return validate_colour_table(table)


def colour_index(bgr: np.ndarray) -> np.ndarray:
    """int32 (H, W) table row of every pixel of a uint8 BGR image (H, W, 3): r//8 + 32*(g//8) + 1024*(b//8)."""
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ValueError(f"expected a uint8 HxWx3 BGR image, got {bgr.dtype} {bgr.shape}")
    quant = (bgr >> 3).astype(np.int32)
    return quant[..., 2] + 32 * quant[..., 1] + 1024 * quant[..., 0]


def colour_attributes(bgr: np.ndarray, table: np.ndarray) -> np.ndarray:
    """float32 (H, W, 10): colour attributes of every pixel of a uint8 BGR image, from a (32768, 10) table."""
    return table[colour_index(bgr)]
