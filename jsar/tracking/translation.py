"""The STRCF translation filter: a spatially and temporally regularised correlation filter.

Works on feature maps in cells (H, W, C) of a square search patch centred on the target.
Also serves as JSAR-Re's decision filter (same features and solver, its own previous filter).
"""
from __future__ import annotations

import numpy as np

from jsar import dcf, fourier
from jsar.config import JsarParams


class TranslationFilter:
    """STRCF model with its own previous filter: `train(xf)`, `response(zf)`.

    `shape_hw` is the feature map size in cells (50 x 50 by default); `target_cells_hw` the
    target's size in those cells (sets the label width once and the regularisation box, which
    `set_target_cells` reshapes when the aspect ratio changes).
    """

    def __init__(self, params: JsarParams, shape_hw: tuple[int, int], target_cells_hw: tuple[float, float]):
        self.params = params
        self.shape_hw = (int(shape_hw[0]), int(shape_hw[1]))
        floored = (int(np.floor(target_cells_hw[0])), int(np.floor(target_cells_hw[1])))
        sigma = dcf.label_sigma(floored, params.output_sigma_factor)
        self.label_f = fourier.rfft2(dcf.gaussian_label(self.shape_hw, sigma))
        self.cos_window = dcf.hann_window(self.shape_hw)
        self.reg_window = dcf.regularisation_window(
            self.shape_hw, target_cells_hw, params.reg_window_inside, params.reg_window_outside)
        self.filter_f: np.ndarray | None = None  # (C, H, W//2+1) complex64 once trained

    @property
    def trained(self) -> bool:
        """True once `train` has run (since construction or `reset`)."""
        return self.filter_f is not None

    def reset(self) -> None:
        """Forget the filter: the next `train` is a first frame (no temporal term)."""
        self.filter_f = None

    def set_target_cells(self, target_cells_hw: tuple[float, float]) -> None:
        """Reshape the regularisation box to the target's current size in cells (aspect change)."""
        self.reg_window = dcf.regularisation_window(
            self.shape_hw, target_cells_hw, self.params.reg_window_inside,
            self.params.reg_window_outside)

    def sample_spectrum(self, features_hwc: np.ndarray) -> np.ndarray:
        """(H, W, C) features -> (C, H, W//2+1) complex64 spectrum of the cosine-windowed stack."""
        if features_hwc.shape[:2] != self.shape_hw:
            raise ValueError(f"features are {features_hwc.shape[:2]} cells, filter expects {self.shape_hw}")
        stack = np.moveaxis(features_hwc, -1, 0) * self.cos_window[None]
        return fourier.rfft2(stack.astype(np.float32, copy=False))

    def train(self, sample_f: np.ndarray) -> None:
        """One STRCF update on a sample spectrum (the previous filter is the temporal anchor)."""
        if self.filter_f is not None and self.filter_f.shape != sample_f.shape:
            raise ValueError(f"sample spectrum {sample_f.shape} does not match the filter {self.filter_f.shape}")
        p = self.params
        self.filter_f = dcf.admm_solve(
            sample_f, self.label_f, self.reg_window, self.filter_f, lam=p.admm_lambda,
            mu=p.temporal_mu, iterations=p.admm_iterations, penalty_init=p.admm_penalty_init,
            penalty_growth=p.admm_penalty_growth, penalty_max=p.admm_penalty_max)

    def response(self, sample_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(response (H, W) float32 with peak at the displacement, its half spectrum)."""
        if self.filter_f is None:
            raise RuntimeError("TranslationFilter.response called before train")
        resp_f = dcf.response_spectrum(self.filter_f, sample_f)
        return fourier.irfft2(resp_f, self.shape_hw).astype(np.float32), resp_f

    def locate(self, sample_f: np.ndarray) -> tuple[float, float, float]:
        """(dy, dx, peak): sub-cell displacement in cells and the raw response peak."""
        resp, resp_f = self.response(sample_f)
        return dcf.subpixel_peak(resp, resp_f, self.params.newton_iterations)
