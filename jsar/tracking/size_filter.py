"""JSAR's joint scale x aspect-ratio size filter: a DSST-style 2-D filter over the size grid.

Grid cell (i, j), i = scale index, j = aspect index, centre c = (S-1)/2 (resp. (A-1)/2), holds
the patch of size (w * gamma^(i-c) * phi^(j-c), h * gamma^(i-c) / phi^(j-c)) pixels around the
target centre (paper eq. 5): area changes only along i, the w/h ratio only along j (by phi^2 per
cell). The estimate takes exactly the size of the winning cell, so sampling and update agree
(the original updates the ratio by phi^2 per cell on top of that, i.e. twice the sampled step).
Each patch is resampled to the model size, described by fHOG (31 channels, cell 4) and
vectorised; the filter is learned over the grid with the label peak at the grid centre.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import scipy.fft as sfft

from jsar.config import JsarParams
from jsar.features import fhog, patches
from jsar.features._native import kernels


def model_size(target_wh: tuple[float, float], max_area: float, min_side: int, cell: int) -> tuple[int, int]:
    """(w, h) px of the patch model: target aspect, area <= max_area, sides multiples of `cell` >= min_side."""
    w, h = target_wh
    factor = math.sqrt(max_area / (w * h)) if w * h > max_area else 1.0
    # Round to whole cells so fHOG uses every pixel; tiny targets are enlarged to min_side.
    mw = max(min_side, int(round(w * factor / cell)) * cell)
    mh = max(min_side, int(round(h * factor / cell)) * cell)
    return mw, mh


def grid_exponents(count: int) -> np.ndarray:
    """(count,) signed exponents -c..c of the grid steps along one axis."""
    return np.arange(count, dtype=np.float64) - (count - 1) / 2.0


def grid_sizes(size_wh: tuple[float, float], params: JsarParams) -> np.ndarray:
    """(S, A, 2) patch sizes (w, h) px: w * g^ns * p^na, h * g^ns / p^na (paper eq. 5)."""
    scale = params.scale_step ** grid_exponents(params.num_scales)[:, None]
    aspect = params.aspect_step ** grid_exponents(params.num_aspects)[None, :]
    w = size_wh[0] * scale * aspect
    h = size_wh[1] * scale / aspect
    return np.stack([w, h], axis=-1)


def dft_matrix(n: int) -> np.ndarray:
    """(n, n) complex64 forward DFT matrix exp(-2 pi i j k / n) (unnormalised, as rfft/fft)."""
    k = np.arange(n)
    return np.exp(-2j * np.pi * np.outer(k, k) / n).astype(np.complex64)


def half_twiddles(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n//2+1, n) float32 cos and sin of 2 pi k m / n for k = 0..n//2 (the sine rows k = 0 and n/2 exactly 0)."""
    angle = 2.0 * np.pi * np.outer(np.arange(n // 2 + 1), np.arange(n)) / n
    sin = np.sin(angle)
    sin[0] = 0.0
    if n % 2 == 0:
        sin[-1] = 0.0
    return np.cos(angle).astype(np.float32), sin.astype(np.float32)


def grid_spectrum_reference(sample: np.ndarray, window: np.ndarray) -> np.ndarray:
    """(S, A//2+1, D) complex64 rfft2 over the grid axes of `sample` (S, A, D) float32 times `window` (S, A):
    the numpy specification of `kernels.grid_spectrum`, as two DFT-matrix products."""
    n_s, n_a = window.shape
    windowed = (sample * window[:, :, None]).astype(np.complex64)
    half = np.matmul(dft_matrix(n_a)[: n_a // 2 + 1], windowed)  # (S, A//2+1, D)
    return (dft_matrix(n_s) @ half.reshape(n_s, -1)).reshape(half.shape)


def dsst_train_reference(
    numerator: np.ndarray | None, denominator: np.ndarray | None, label_f: np.ndarray, sample_f: np.ndarray,
    rate: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(numerator (S, A', D) complex64, denominator (S, A') float32) after DSST's update with `sample_f`:
    (1 - rate) old + rate new, new = (Y X^*, sum_d |X_d|^2); the new pair itself when there is no old one.
    The numpy specification of `kernels.grid_train`."""
    num = label_f[:, :, None] * sample_f.conj()
    den = (sample_f.real**2 + sample_f.imag**2).sum(axis=-1)
    if numerator is None or denominator is None:
        return num, den
    rate32 = np.float32(rate)
    return numerator * np.float32(1 - rate32) + num * rate32, (1 - rate32) * denominator + rate32 * den


def dsst_response_spectrum_reference(
    numerator: np.ndarray, denominator: np.ndarray, sample_f: np.ndarray, lam: float
) -> np.ndarray:
    """(S, A') complex64 sum_d numerator_d X_d / (denominator + lam): the numpy specification of
    `kernels.grid_response`."""
    return (numerator * sample_f).sum(axis=-1) / (denominator + np.float32(lam))


def grid_label(params: JsarParams) -> np.ndarray:
    """(S, A) float32 Gaussian over the grid, peak 1 at the centre cell, sigmas in grid cells."""
    ns = grid_exponents(params.num_scales)[:, None]
    na = grid_exponents(params.num_aspects)[None, :]
    return np.exp(-0.5 * (ns**2 / params.size_sigma_scale**2 + na**2 / params.size_sigma_aspect**2)).astype(np.float32)


def grid_window(params: JsarParams) -> np.ndarray:
    """(S, A) float32 Hann window over the grid (zero-free), DSST's scale window in 2-D."""

    def hann_1d(n: int) -> np.ndarray:
        k = np.arange(1, n + 1)
        return 0.5 * (1.0 - np.cos(2.0 * np.pi * k / (n + 1)))

    if not params.size_grid_window:
        return np.ones((params.num_scales, params.num_aspects), np.float32)
    return np.outer(hann_1d(params.num_scales), hann_1d(params.num_aspects)).astype(np.float32)


class SizeFilter:
    """The 2-D size filter: `sample` the grid, `estimate` the best cell, `train` DSST-style.

    Spectra are over the (S, A) grid axes with the vectorised patch features as channels:
    numerator = Y X_c^* (per channel, stored in this conjugated form), denominator =
    sum_c |X_c|^2, both updated with the size learning rate; response =
    IFFT(sum_c num_c Z_c / (den + lambda)) (MATLAB scaling), i.e. DSST's conj(Y^* X) Z.
    """

    def __init__(self, params: JsarParams, init_size_wh: tuple[float, float]):
        self.params = params
        self.model_wh = model_size(init_size_wh, params.size_model_max_area,
                                   params.size_model_min_side, params.cell_size)
        self.grid_shape = (params.num_scales, params.num_aspects)
        self.label_f = sfft.rfft2(grid_label(params), workers=1).astype(np.complex64)  # (S, A//2+1)
        self.window = grid_window(params)
        self._twiddles_aspect = half_twiddles(params.num_aspects)
        self._twiddles_scale = half_twiddles(params.num_scales)
        self.numerator: np.ndarray | None = None  # (S, A//2+1, D) complex64
        self.denominator: np.ndarray | None = None  # (S, A//2+1) float32

    def sample(self, frame: np.ndarray, centre_xy: tuple[float, float], size_wh: tuple[float, float]) -> np.ndarray:
        """(S, A, D) float32: vectorised fHOG of every grid patch around `centre_xy` (unwindowed)."""
        sizes = grid_sizes(size_wh, self.params).reshape(-1, 2)
        return self._features(frame, centre_xy, sizes).reshape(self.grid_shape[0], self.grid_shape[1], -1)

    def shifted_sample(
        self, frame: np.ndarray, centre_xy: tuple[float, float], size_wh: tuple[float, float],
        previous: np.ndarray, shift: tuple[int, int],
    ) -> np.ndarray:
        """The grid sample at `size_wh` = the size of cell (c + di, c + dj) of `previous`.

        `previous` was sampled at the same centre with the grid shifted by `shift` = (di, dj)
        cells, so cell (i, j) now holds what previous cell (i + di, j + dj) held; only the cells
        that fall outside the previous grid are sampled (the same result as `sample`, for a
        fraction of the crops).
        """
        di, dj = shift
        n_s, n_a = self.grid_shape
        out = np.empty_like(previous)
        src_i = np.arange(n_s) + di
        src_j = np.arange(n_a) + dj
        keep_i = (src_i >= 0) & (src_i < n_s)
        keep_j = (src_j >= 0) & (src_j < n_a)
        out[np.ix_(keep_i, keep_j)] = previous[np.ix_(src_i[keep_i], src_j[keep_j])]
        missing = ~(keep_i[:, None] & keep_j[None, :])
        if missing.any():
            sizes = grid_sizes(size_wh, self.params)[missing]
            out[missing] = self._features(frame, centre_xy, sizes)
        return out

    def _features(self, frame: np.ndarray, centre_xy: tuple[float, float], sizes: np.ndarray) -> np.ndarray:
        """(N, D) float32 vectorised fHOG of the N patches of `sizes` (N, 2) px around `centre_xy`."""
        if frame.ndim == 3:
            # fHOG of the size filter runs on luminance: convert only the region the grid covers.
            frame, centre_xy = grey_region(frame, centre_xy, sizes.max(axis=0))
        crops = patches.sample_patches(frame, centre_xy, sizes, self.model_wh)
        return fhog.fhog_batch(crops, self.params.cell_size).reshape(len(sizes), -1)

    def spectrum(self, sample: np.ndarray) -> np.ndarray:
        """(S, A//2+1, D) complex64 spectrum of an (S, A, D) grid sample (windowed if configured): rfft2 over
        the grid axes (`grid_spectrum_reference`), compiled."""
        n_s, n_a, channels = sample.shape
        half = n_a // 2 + 1
        out = np.empty((n_s, half, channels), np.complex64)
        scratch = np.empty((n_s, half, 2, channels), np.float32)
        kernels.grid_spectrum(np.ascontiguousarray(sample, dtype=np.float32), self.window, *self._twiddles_aspect,
                              *self._twiddles_scale, scratch, out, n_s, n_a, channels)
        return out

    def train(self, sample_f: np.ndarray) -> None:
        """DSST update (`dsst_train_reference`), compiled: the first call sets the model, later calls
        interpolate with the learning rate. The numerator is kept conjugated (Y X^*), the form the response
        multiplies with."""
        sample_f = np.ascontiguousarray(sample_f, dtype=np.complex64)
        first = self.numerator is None or self.denominator is None
        if first:
            self.numerator = np.empty_like(sample_f)
            self.denominator = np.empty(sample_f.shape[:2], np.float32)
        frequencies = sample_f.shape[0] * sample_f.shape[1]
        kernels.grid_train(self.label_f, sample_f, self.numerator, self.denominator,
                           float(np.float32(self.params.size_learning_rate)), first, frequencies, sample_f.shape[2])

    def response(self, sample_f: np.ndarray) -> np.ndarray:
        """(S, A) float32 response over the grid (`dsst_response_spectrum_reference`, compiled, then the inverse
        DFT); the peak cell is the size estimate (best_cell, refined_position)."""
        if self.numerator is None or self.denominator is None:
            raise RuntimeError("SizeFilter.response called before train")
        sample_f = np.ascontiguousarray(sample_f, dtype=np.complex64)
        resp_f = np.empty(sample_f.shape[:2], np.complex64)
        kernels.grid_response(self.numerator, sample_f, self.denominator, float(np.float32(self.params.size_lambda)),
                              resp_f, resp_f.size, sample_f.shape[2])
        return sfft.irfft2(resp_f, s=self.grid_shape, workers=1).astype(np.float32)

    def cell_factors(self, i: float, j: float) -> tuple[float, float]:
        """(width factor, height factor) of grid position (i, j) (fractional allowed) relative to the current size."""
        ns = i - (self.grid_shape[0] - 1) / 2.0
        na = j - (self.grid_shape[1] - 1) / 2.0
        scale = self.params.scale_step**ns
        aspect = self.params.aspect_step**na
        return scale * aspect, scale / aspect


def best_cell(resp: np.ndarray) -> tuple[int, int]:
    """(i, j) cell of the maximum of an (S, A) grid response."""
    i, j = np.unravel_index(int(np.argmax(resp)), resp.shape)
    return int(i), int(j)


def refined_position(resp: np.ndarray, deadband_cells: float = 0.0) -> tuple[float, float]:
    """(i, j) fractional grid position of the maximum of an (S, A) response: argmax + a parabola per
    axis, each axis's offset from the grid centre set to 0 when below deadband_cells (grid cells).

    The grid is periodic (the response is an inverse DFT), so the neighbours wrap around.
    """
    i, j = best_cell(resp)
    n_s, n_a = resp.shape
    di = parabola_offset(resp[(i - 1) % n_s, j], resp[i, j], resp[(i + 1) % n_s, j])
    dj = parabola_offset(resp[i, (j - 1) % n_a], resp[i, j], resp[i, (j + 1) % n_a])
    centre_i, centre_j = (n_s - 1) / 2.0, (n_a - 1) / 2.0
    fi, fj = i + di, j + dj
    return (centre_i if abs(fi - centre_i) < deadband_cells else fi,
            centre_j if abs(fj - centre_j) < deadband_cells else fj)


def updated_mean(mean: float | None, value: float, rate: float) -> float:
    """Running mean: `value` itself first, then mean + rate * (value - mean)."""
    return value if mean is None else mean + rate * (value - mean)


def parabola_offset(left: float, centre: float, right: float) -> float:
    """Offset in [-0.5, 0.5] of the vertex of the parabola through (-1, left), (0, centre), (1, right)."""
    curvature = left - 2.0 * centre + right
    if curvature >= 0.0:  # not a maximum: keep the sample
        return 0.0
    return float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5))


def clamp_size(
    size_wh: tuple[float, float], min_side: float, image_wh: tuple[int, int], ratio_band: tuple[float, float]
) -> tuple[float, float]:
    """(w, h) with w/h inside ratio_band = (lo, hi), sides >= min_side and <= the image size.

    The ratio is clamped first keeping the area, then the sides; a side clamp keeps the other.
    """
    w, h = size_wh
    lo, hi = ratio_band
    ratio = w / h
    if ratio < lo or ratio > hi:
        area = w * h
        ratio = min(max(ratio, lo), hi)
        w, h = math.sqrt(area * ratio), math.sqrt(area / ratio)
    w = min(max(w, min_side), float(image_wh[0]))
    h = min(max(h, min_side), float(image_wh[1]))
    return w, h


def bound_side(size_wh: tuple[float, float], side_bounds_px: tuple[float, float] | None) -> tuple[float, float]:
    """(w, h) px scaled about its aspect ratio so that sqrt(w*h) lies in side_bounds_px = (lo, hi) px (None: as is)."""
    if side_bounds_px is None:
        return size_wh
    w, h = size_wh
    lo, hi = side_bounds_px
    side = math.sqrt(w * h)
    factor = min(max(side, lo), hi) / side
    return w * factor, h * factor


def grey_region(
    frame: np.ndarray, centre_xy: tuple[float, float], extent_wh: np.ndarray
) -> tuple[np.ndarray, tuple[float, float]]:
    """(grey crop, centre in crop coordinates) of the BGR frame region of size extent_wh around centre.

    The crop is clipped to the image and carries a 2 px margin, so resampling any region inside
    `extent_wh` reads the same pixels (and the same replicated border) as on the full frame.
    """
    height, width = frame.shape[:2]
    half_w, half_h = extent_wh[0] / 2.0 + 2.0, extent_wh[1] / 2.0 + 2.0
    x0 = max(0, int(math.floor(centre_xy[0] - half_w)))
    x1 = min(width, int(math.ceil(centre_xy[0] + half_w)) + 1)
    y0 = max(0, int(math.floor(centre_xy[1] - half_h)))
    y1 = min(height, int(math.ceil(centre_xy[1] + half_h)) + 1)
    if x1 <= x0 or y1 <= y0:  # region entirely off the image: its nearest border pixels
        x0, x1 = (0, 1) if x1 <= 0 else (width - 1, width) if x0 >= width else (x0, x1)
        y0, y1 = (0, 1) if y1 <= 0 else (height - 1, height) if y0 >= height else (y0, y1)
    grey = cv2.cvtColor(frame[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY)
    return grey, (centre_xy[0] - x0, centre_xy[1] - y0)
