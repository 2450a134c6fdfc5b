"""Translation-filter features: gray + fHOG + colour attributes per cell, stacked channel-wise.

Channel order (what the filters see), for a patch of H x W pixels and cell c (H // c x W // c cells):
- 0: gray, pixel / 255 - 0.5 averaged over each cell (colour patches: cv2 BGR2GRAY first);
- 1..31: fHOG (see `jsar.features.fhog`; colour patches: strongest channel per pixel);
- 32..41: colour attributes from a (32768, 10) table (see `jsar.features.colour`), averaged over
  each cell; only when `colour_table` is given (42 channels), else 32 channels.
Pixels beyond the last whole cell are ignored, like fHOG does.
"""
from __future__ import annotations

import cv2
import numpy as np

from jsar.features import fhog as fhog_features  # fhog_batch looked up at call time: bench.profile marks it there
from jsar.features._native import kernels as _kernels
from jsar.features.colour import colour_attributes


def cell_mean(values: np.ndarray, cell: int) -> np.ndarray:
    """float32 (H//cell, W//cell, C): mean of `values` (H, W, C) over each cell x cell block."""
    hc, wc = values.shape[0] // cell, values.shape[1] // cell
    blocks = values[: hc * cell, : wc * cell].reshape(hc, cell, wc, cell, values.shape[2])
    return blocks.mean(axis=(1, 3), dtype=np.float32)


def _check_patch(patch: object, cell: int, colour_table: np.ndarray | None) -> np.ndarray:
    if not isinstance(patch, np.ndarray):
        raise ValueError(f"patch must be a numpy array, got {type(patch).__name__}")
    if patch.dtype != np.uint8:
        raise ValueError(f"patch must be uint8 (0..255), got dtype {patch.dtype}")
    if not (patch.ndim == 2 or (patch.ndim == 3 and patch.shape[2] == 3)):
        raise ValueError(f"patch must be HxW grey or HxWx3 BGR, got shape {patch.shape}")
    if not isinstance(cell, (int, np.integer)) or cell < 1:
        raise ValueError(f"cell must be a positive integer, got {cell!r}")
    if patch.shape[0] < cell or patch.shape[1] < cell:
        raise ValueError(f"patch {patch.shape} is smaller than one {cell}x{cell} cell")
    if colour_table is not None:
        if patch.ndim == 2:
            raise ValueError("colour_table given for a grey patch: pass colour_table=None for grey input")
        if not (isinstance(colour_table, np.ndarray) and colour_table.shape == (32768, 10)
                and colour_table.dtype == np.float32 and colour_table.flags.c_contiguous):
            raise ValueError("colour_table must be C-contiguous float32 (32768, 10): build or load it with jsar.features.colour")
    return patch


def extract_features(patch: np.ndarray, cell: int = 4, colour_table: np.ndarray | None = None) -> np.ndarray:
    """float32 (H//cell, W//cell, 42 or 32): gray, fHOG, colour attributes of a uint8 BGR / grey patch."""
    _check_patch(patch, cell, colour_table)
    grey = patch if patch.ndim == 2 else cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
    height, width = patch.shape[:2]
    hc, wc = height // cell, width // cell
    n_channels = 1 + fhog_features.N_CHANNELS + (0 if colour_table is None else colour_table.shape[1])
    out = np.empty((hc, wc, n_channels), np.float32)
    # cv2's area resize by the whole factor 1/cell is the exact cell mean (and ~8x faster than numpy).
    visible = grey[: hc * cell, : wc * cell].astype(np.float32)
    out[..., 0] = cv2.resize(visible, (wc, hc), interpolation=cv2.INTER_AREA) * np.float32(1.0 / 255.0) - np.float32(0.5)
    # fHOG and the colour cells are written straight into the stack (each cell n_channels floats after the
    # last): the same numbers as separate arrays copied in, without the copies.
    src = np.ascontiguousarray(patch)
    fhog_features.fhog_batch(src[None], cell, stack=out[None], channel=1)
    if colour_table is not None:
        _kernels.colour_cells(src, height, width, colour_table, colour_table.shape[1], int(cell),
                              out.reshape(-1)[1 + fhog_features.N_CHANNELS:], n_channels)
    return out


def colour_cells_reference(patch: np.ndarray, cell: int, colour_table: np.ndarray) -> np.ndarray:
    """numpy reference of the colour channels: per-pixel table rows averaged over each cell."""
    return cell_mean(colour_attributes(patch, colour_table), cell)


def colour_cells_reference_loops(patch: np.ndarray, cell: int, colour_table: np.ndarray) -> np.ndarray:
    """The colour channels through the compiled kernel's loops of abi 5 (`colour_cells_reference`): the numbers
    `extract_features` must give to the bit (its faster loops are tested against these)."""
    _check_patch(patch, cell, colour_table)
    out = np.empty((patch.shape[0] // cell, patch.shape[1] // cell, colour_table.shape[1]), np.float32)
    _kernels.colour_cells_reference(np.ascontiguousarray(patch), patch.shape[0], patch.shape[1], colour_table,
                                    colour_table.shape[1], int(cell), out)
    return out
