"""Correlation-filter math: labels, windows, the STRCF ADMM solve, responses and sub-cell peaks.

Conventions: feature stacks are channels first, (C, H, W) in cells; spectra are rfft2 half
spectra (C, H, W//2+1) complex64 in the MATLAB scaling (forward unnormalised, inverse 1/N, see
jsar.fourier). Position (0, 0) is the label peak and "zero displacement"; a response peak at
(dy, dx) (wrapped to [-H/2, H/2) x [-W/2, W/2)) means the target moved by +dy rows, +dx cols.
The response is r(t) = sum_c sum_n f_c(n) x_c(n + t), i.e. spectrum sum_c conj(F_c) X_c.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

from jsar import fourier
from jsar.features._native import kernels


def gaussian_label(shape_hw: tuple[int, int], sigma: float) -> np.ndarray:
    """(H, W) float32 Gaussian of std `sigma` cells, peak 1 at (0, 0), circularly wrapped."""
    height, width = shape_hw
    if sigma <= 0:
        raise ValueError(f"label sigma must be > 0, got {sigma}")
    rows = np.fft.fftfreq(height, 1.0 / height)  # 0, 1, ..., -2, -1: offsets from (0, 0)
    cols = np.fft.fftfreq(width, 1.0 / width)
    return np.exp(-0.5 * (rows[:, None] ** 2 + cols[None, :] ** 2) / sigma**2).astype(np.float32)


def label_sigma(target_cells_hw: tuple[int, int], sigma_factor: float) -> float:
    """Label std in cells: factor * sqrt(prod(target size in whole cells)) (at least one cell area)."""
    return sigma_factor * math.sqrt(max(1, target_cells_hw[0]) * max(1, target_cells_hw[1]))


def hann_window(shape_hw: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 cosine window without zero rows (hann(n+2) with its end points dropped)."""

    def hann_1d(n: int) -> np.ndarray:
        k = np.arange(1, n + 1)
        return 0.5 * (1.0 - np.cos(2.0 * np.pi * k / (n + 1)))

    return np.outer(hann_1d(shape_hw[0]), hann_1d(shape_hw[1])).astype(np.float32)


def regularisation_window(
    shape_hw: tuple[int, int], target_cells_hw: tuple[float, float], inside: float, outside: float
) -> np.ndarray:
    """(H, W) float32 spatial penalty: `inside` on a centred box of floor(target) cells, else `outside`.

    The filter's support sits at the array centre because the training patch is centred on the
    target. The box is at least 1 cell and at most the whole array.
    """
    height, width = shape_hw
    box_h = int(min(height, max(1, math.floor(target_cells_hw[0]))))
    box_w = int(min(width, max(1, math.floor(target_cells_hw[1]))))
    window = np.full(shape_hw, outside, dtype=np.float32)
    top = (height - box_h) // 2
    left = (width - box_w) // 2
    window[top : top + box_h, left : left + box_w] = inside
    return window


def response_spectrum(filter_f: np.ndarray, sample_f: np.ndarray) -> np.ndarray:
    """(H, W//2+1) spectrum of the response: sum_c conj(F_c) * X_c (channels first)."""
    product = filter_f.conj()
    product *= sample_f
    return product.sum(axis=0)


def windowed_channels_last(windows: np.ndarray, cos_window: np.ndarray) -> np.ndarray:
    """(M, H, W, C) float32 channels-last feature windows times the (H, W) cosine window, compiled: the numbers of
    `windows * cos_window[None, :, :, None]` (one product each)."""
    windows = np.ascontiguousarray(windows, dtype=np.float32)
    m, h, w, c = windows.shape
    if cos_window.shape != (h, w):
        raise ValueError(f"cos_window {cos_window.shape} does not match the windows' {(h, w)}")
    out = np.empty_like(windows)
    kernels.window_channels_last(windows, np.ascontiguousarray(cos_window, dtype=np.float32), out, m, h * w, c)
    return out


def response_spectra_reference(filter_f: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """(M, H, W//2+1) complex64 response spectra sum_c conj(F_c) X_mc of channels-last spectra (M, H, W//2+1, C)
    under one channels-first filter (C, H, W//2+1): the numpy specification of `response_spectra`."""
    filter_hwc = np.ascontiguousarray(np.moveaxis(filter_f.conj(), 0, -1))
    return np.einsum("hwc,mhwc->mhw", filter_hwc, spectra)


def response_spectra(filter_f: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """`response_spectra_reference`, compiled: the same sums in the same order (channel by channel, in float),
    without the filter's channels-last copy."""
    filter_f = np.ascontiguousarray(filter_f, dtype=np.complex64)
    spectra = np.ascontiguousarray(spectra, dtype=np.complex64)
    c, h, w2 = filter_f.shape
    m = spectra.shape[0]
    if spectra.shape != (m, h, w2, c):
        raise ValueError(f"spectra {spectra.shape} do not match the filter's (M, {h}, {w2}, {c})")
    out = np.empty((m, h, w2), dtype=np.complex64)
    kernels.response_spectra(filter_f, spectra, out, m, h * w2, c)
    return out


# A chunk of windows goes through the window -> FFT -> correlation chain while its features and spectra are still
# in the core's cache: for 50 x 50 cells of 42 channels a window is 0.42 MB of features and 0.44 MB of spectra, and a
# lost frame's 9 windows, stacked whole (3.8 MB, then 4 MB of spectra), ran the chain from memory and faulted fresh
# pages in (docs/results-cost.md, "In time, here").
WINDOW_CHAIN_BYTES = 2 << 20


def window_response_spectra(filter_f: np.ndarray, windows: Sequence[np.ndarray], cos_window: np.ndarray,
                            chunk_bytes: int = WINDOW_CHAIN_BYTES) -> np.ndarray:
    """(M, H, W//2+1) complex64 response spectra of M channels-last feature windows (H, W, C) float32 (views
    allowed) under one channels-first filter (C, H, W//2+1): `response_spectra(filter_f, rfft2_channels_last(
    windowed_channels_last(np.stack(windows), cos_window)))`, run over chunks of at most chunk_bytes of features
    and spectra (at least one window): the same numbers, each window's transform being its own."""
    if not windows:
        raise ValueError("window_response_spectra needs at least one window")
    h, w, c = windows[0].shape
    per_window = h * w * c * 4 + h * (w // 2 + 1) * c * 8
    step = max(1, chunk_bytes // per_window)
    out = np.empty((len(windows), h, w // 2 + 1), dtype=np.complex64)
    for start in range(0, len(windows), step):
        part = np.stack(windows[start:start + step])
        out[start:start + len(part)] = response_spectra(
            filter_f, fourier.rfft2_channels_last(windowed_channels_last(part, cos_window)))
    return out


def response(filter_f: np.ndarray, sample_f: np.ndarray, shape_hw: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 response IFFT(sum_c conj(F_c) X_c) in the MATLAB scaling; peak at the shift."""
    return fourier.irfft2(response_spectrum(filter_f, sample_f), shape_hw).astype(np.float32)


def wrap_displacement(index: float, size: int) -> float:
    """Cell index in [0, size) -> signed displacement in [-size/2, size/2)."""
    return ((index + size / 2.0) % size) - size / 2.0


def subpixel_peak(
    resp: np.ndarray, resp_f: np.ndarray, iterations: int
) -> tuple[float, float, float]:
    """(dy, dx, peak): the response maximum refined by Newton steps on its Fourier interpolant.

    `resp` is the (H, W) response, `resp_f` its half spectrum. dy, dx are signed displacements
    in cells (wrapped); `peak` is the raw maximum of `resp` on the cell grid (the confidence the
    JSAR-Re thresholds are defined on). A Newton step that leaves the starting cell's
    neighbourhood, or a non-concave point, stops the refinement (the grid maximum is kept).
    """
    height, width = resp.shape
    flat = int(np.argmax(resp))
    row, col = divmod(flat, width)
    peak = float(resp[row, col])
    y, x = float(row), float(col)
    interpolant = fourier.Interpolant(resp_f, (height, width))
    for _ in range(iterations):
        dy, dx, dyy, dxx, dxy = interpolant.derivatives(y, x)
        det = dyy * dxx - dxy * dxy
        if not (dyy < 0 and det > 0):
            break  # not at a concave point: Newton would walk to a saddle or a minimum
        # Newton step: -H^{-1} grad, with the 2x2 inverse written out.
        step_y = (dxx * dy - dxy * dx) / det
        step_x = (dyy * dx - dxy * dy) / det
        y_new, x_new = y - step_y, x - step_x
        if abs(y_new - row) > 1.0 or abs(x_new - col) > 1.0:
            break
        y, x = y_new, x_new
        if abs(step_y) < 1e-3 and abs(step_x) < 1e-3:
            break
    return wrap_displacement(y, height), wrap_displacement(x, width), peak


def admm_solve(
    sample_f: np.ndarray,
    label_f: np.ndarray,
    reg_window: np.ndarray,
    previous_f: np.ndarray | None,
    *,
    lam: float,
    mu: float,
    iterations: int,
    penalty_init: float,
    penalty_growth: float,
    penalty_max: float,
    box_transforms: bool | None = None,
    kernel: bool | None = None,
) -> np.ndarray:
    """STRCF filter spectrum (C, H, W//2+1) complex64 minimising, by ADMM,

        E(f) = 1/2 sum_k |sum_c conj(F_c) X_c - Y|^2 + N lam/2 ||reg_window * f||^2
               + N mu/2 sum_k ||F - F_prev||^2,

    with sums over the full spectrum in MATLAB units, f = IFFT(F) the spatial filter and
    N = H*W. These are the units of STRCF's reference code (its per-frequency system is
    x x^H / N + (penalty + mu)), which is what the paper's mu = 16 and penalty schedule mean.
    Split f = g (g carries the spatial penalty); the f-step is a per-frequency rank-one system
    solved by Sherman-Morrison over channels, the g-step is element-wise in the spatial domain.
    mu is ignored (0) when `previous_f` is None (first frame). The last g-step is skipped: it
    would not change the returned f. Returns F (the unconstrained split variable), which after
    the last, large-penalty iteration agrees with the constrained g to within the ADMM residual.

    For the two-valued box windows of `regularisation_window` the g-step is done without full
    FFTs (same result up to float32 rounding): 1 / (lam w^2 + p) = a + b * box, so
    G = a (p F + H) + DFT(b * box * IDFT(p F + H)), where the inverse DFT is needed on the box
    only and the forward DFT of a box-supported signal is two small matrix products.
    `box_transforms`: None = use them when the window is such a box covering <= 1/4 of the
    map, False = always full FFTs, True = require the box path (ValueError if not a box).
    `kernel`: None or True = the element-wise work of each iteration in one compiled pass
    (`_admm_iterations_compiled`; it rounds as this code does where numpy's complex product uses FMA, as on
    x86-64 with AVX2, and equals it to the bit there), False = this numpy code (the reference).
    """
    height = sample_f.shape[1]
    shape_hw = (height, reg_window.shape[1])
    n = float(height * shape_hw[1])
    if previous_f is None:
        mu = 0.0
    # Work with the system multiplied by N: penalty and mu scaled by N, data term as is.
    mu_n = mu * n
    reg_sq = np.float32(lam) * reg_window.astype(np.float32) ** 2
    box = _two_valued_box(reg_window)
    if box_transforms and box is None:
        raise ValueError("box_transforms=True needs a two-valued rectangular regularisation window")
    if box is not None and box_transforms is None:
        (r0, r1, c0, c1), _, _ = box
        if (r1 - r0) * (c1 - c0) * 4 > height * shape_hw[1]:
            box = None
    if box_transforms is False:
        box = None
    partial = _box_dft(shape_hw, box[0]) if box is not None else None
    if kernel is None or kernel:
        return _admm_iterations_compiled(
            sample_f, label_f, previous_f if mu > 0.0 else None, reg_sq, box, partial, shape_hw, lam=lam,
            mu_n=mu_n, iterations=iterations, penalty=penalty_init * n, penalty_growth=penalty_growth,
            penalty_cap=penalty_max * n)
    # Terms that do not change over the iterations.
    sample_conj = sample_f.conj()
    sxx = (sample_conj * sample_f).real.sum(axis=0)
    constant = sample_f * np.conj(label_f)[None]
    if mu > 0.0:
        constant += np.complex64(mu_n) * previous_f
    # Work buffers, reused across iterations: fresh large temporaries cost page faults.
    q = np.empty_like(sample_f)  # right-hand side, then the f-step solution
    tmp = np.empty_like(sample_f)
    g_f = np.zeros_like(sample_f)
    h_f = np.zeros_like(sample_f)
    penalty = penalty_init * n
    penalty_cap = penalty_max * n
    for it in range(iterations):
        # f-step: (x x^H + (mu + p) I) f = q, q = x conj(y) + mu f_prev + p g - h,
        # solved per frequency by Sherman-Morrison.
        if it == 0:
            np.copyto(q, constant)  # g = h = 0
        else:
            np.multiply(g_f, np.float32(penalty), out=q)
            q += constant
            q -= h_f
        np.multiply(sample_conj, q, out=tmp)
        coeff = tmp.sum(axis=0)
        coeff /= sxx + np.float32(mu_n + penalty)
        np.multiply(sample_f, coeff[None], out=tmp)
        q -= tmp
        q *= np.float32(1.0 / (mu_n + penalty))
        if it == iterations - 1:
            break
        # g-step: g = (p f + h) / (lam w^2 + p), spatial, element-wise (p already scaled by N).
        numerator = np.multiply(q, np.float32(penalty), out=tmp)
        numerator += h_f
        outside_weight = _g_step_transforms(numerator, g_f, penalty, lam, box, partial, reg_sq, shape_hw)
        if outside_weight is not None:
            numerator *= np.float32(outside_weight)
            g_f += numerator
        # dual ascent on the constraint f = g
        np.subtract(q, g_f, out=tmp)
        tmp *= np.float32(penalty)
        h_f += tmp
        penalty = min(penalty * penalty_growth, penalty_cap)
    return q


def _admm_iterations_compiled(
    sample_f: np.ndarray,
    label_f: np.ndarray,
    previous_f: np.ndarray | None,
    reg_sq: np.ndarray,
    box: tuple[tuple[int, int, int, int], float, float] | None,
    partial: _BoxDft | None,
    shape_hw: tuple[int, int],
    *,
    lam: float,
    mu_n: float,
    iterations: int,
    penalty: float,
    penalty_growth: float,
    penalty_cap: float,
) -> np.ndarray:
    """`admm_solve`'s iterations (same arguments, penalties and mu already scaled by N) with the
    element-wise work in `kernels.strcf_f_step`: per iteration one compiled pass (the previous
    g-step's box term and dual step, the f-step, the next numerator) and the g-step's transforms."""
    x = np.ascontiguousarray(sample_f, dtype=np.complex64)
    label = np.ascontiguousarray(label_f, dtype=np.complex64)
    previous = None if previous_f is None else np.ascontiguousarray(previous_f, dtype=np.complex64)
    channels, frequencies = x.shape[0], x.shape[1] * x.shape[2]
    constant = np.empty_like(x)
    sxx = np.empty(x.shape[1:], np.float32)
    q = np.empty_like(x)  # the f-step solution
    numerator = np.empty_like(x)  # the g-step's p F + H
    g_f = np.empty_like(x)  # written by every g-step before the kernel reads it
    h_f = np.zeros_like(x)
    penalty_prev = 0.0
    box_weight = 0.0  # the previous g-step's element-wise term, added to g_f by the kernel
    for it in range(iterations):
        last = it == iterations - 1
        kernels.strcf_f_step(x, label, previous, constant, sxx, q, g_f, h_f, numerator, channels, frequencies,
                             mu_n, penalty_prev, penalty, box_weight, float(np.float32(1.0 / (mu_n + penalty))),
                             it == 0, last)
        if last:
            break
        outside_weight = _g_step_transforms(numerator, g_f, penalty, lam, box, partial, reg_sq, shape_hw)
        box_weight = 0.0 if outside_weight is None else float(np.float32(outside_weight))
        penalty_prev = penalty
        penalty = min(penalty * penalty_growth, penalty_cap)
    return q


def _g_step_transforms(numerator: np.ndarray, g_f: np.ndarray, penalty: float, lam: float,
                       box: tuple[tuple[int, int, int, int], float, float] | None, partial: _BoxDft | None,
                       reg_sq: np.ndarray, shape_hw: tuple[int, int]) -> float | None:
    """The g-step's transforms into g_f (C, H, W//2+1) from numerator = p F + H: with a box window
    DFT(b * box * IDFT(numerator)), returning a, whose a * numerator the caller adds (admm_solve's docstring);
    else the whole g-step by full FFTs, returning None."""
    if partial is not None and box is not None:
        _, inside, outside = box
        a = 1.0 / (lam * outside**2 + penalty)
        b = 1.0 / (lam * inside**2 + penalty) - a
        inner = partial.inverse(numerator)
        inner *= np.float32(b)
        partial.forward(inner, out=g_f)
        return a
    spatial = fourier.irfft2(numerator, shape_hw)
    spatial *= (1.0 / (reg_sq + np.float32(penalty)))[None]
    g_f[...] = fourier.rfft2(spatial.astype(np.float32, copy=False))
    return None


def _two_valued_box(window: np.ndarray) -> tuple[tuple[int, int, int, int], float, float] | None:
    """((r0, r1, c0, c1), inside, outside) if `window` is `inside` on one rectangle and `outside`
    elsewhere (inside < outside), else None."""
    inside, outside = float(window.min()), float(window.max())
    if inside == outside:
        return None
    mask = window == window.min()
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    if int(mask.sum()) != (r1 - r0) * (c1 - c0) or not np.all(window[~mask] == window.max()):
        return None
    return (r0, r1, c0, c1), inside, outside


class _BoxDft:
    """Inverse DFT restricted to a box of the (H, W) grid, and forward DFT of box-supported signals.

    Half spectra (C, H, W//2+1) in the MATLAB scaling, exactly the values irfft2 / rfft2 give on (resp. from)
    the box, by two small matrix products per channel and direction. Each direction takes the order of its
    two products (rows or columns first) with fewer multiply-adds for the box's shape: the step with real
    input or output runs as one real matrix product on the complex array's float view (half the
    multiply-adds of a complex product), so a tall box does columns first and a wide one rows first.
    """

    def __init__(self, shape_hw: tuple[int, int], box: tuple[int, int, int, int]):
        height, width = shape_hw
        r0, r1, c0, c1 = box
        ky, kx = fourier.frequencies(shape_hw)
        ys = np.arange(r0, r1)
        xs = np.arange(c0, c1)
        weights = fourier.half_spectrum_weights(shape_hw)
        bh, bw, half = r1 - r0, c1 - c0, len(kx)
        self.box = box
        self.inv_y = _frozen(np.exp(2j * np.pi * np.outer(ys, ky) / height).astype(np.complex64))  # (bh, H)
        self.inv_x = _frozen((weights[:, None] * np.exp(2j * np.pi * np.outer(kx, xs) / width)
                              / (height * width)).astype(np.complex64))  # (W', bw)
        self.fwd_y = _frozen(np.exp(-2j * np.pi * np.outer(ky, ys) / height).astype(np.complex64))  # (H, bh)
        self.fwd_x = _frozen(np.exp(-2j * np.pi * np.outer(xs, kx) / width).astype(np.complex64))  # (bw, W')
        # Real multiply-adds per channel (a complex one counts 4): columns first, or rows first.
        self.inverse_rows_first = (4 * bh * height * half + 2 * bh * half * bw
                                   < 4 * height * half * bw + 4 * bh * height * bw)
        self.forward_rows_first = (2 * height * bh * bw + 4 * height * bw * half
                                   < 2 * bh * bw * half + 4 * height * bh * half)
        # Re(Z X) of an interleaved (re, im) row of Z: rows (Re X[k], -Im X[k]) per frequency k.
        self.inv_x_real = _frozen(np.stack([self.inv_x.real, -self.inv_x.imag], axis=1).reshape(2 * half, bw))
        # b F of a real row b: columns (Re F[:, k], Im F[:, k]) per frequency k.
        self.fwd_x_of_real = _frozen(np.stack([self.fwd_x.real, self.fwd_x.imag], axis=2).reshape(bw, 2 * half))
        # (Zr | Zi) F for Z = Zr + i Zi along the box's columns: rows (Fr, Fi) then (-Fi, Fr), interleaved columns.
        self.fwd_x_of_pair = _frozen(np.concatenate(
            [self.fwd_x_of_real, np.stack([-self.fwd_x.imag, self.fwd_x.real], axis=2).reshape(bw, 2 * half)]))
        self.fwd_y_real = _frozen(np.concatenate([self.fwd_y.real, self.fwd_y.imag]))  # (2H, bh)

    def inverse(self, spectrum: np.ndarray) -> np.ndarray:
        """(C, bh, bw) float32: irfft2(spectrum) on the box."""
        if not self.inverse_rows_first:
            # one product each for all channels: (C H, W') @ (W', bw), then (bh, H) @ (H, C bw)
            channels, height, half = spectrum.shape
            bw = self.inv_x.shape[1]
            columns = (np.ascontiguousarray(spectrum).reshape(channels * height, half) @ self.inv_x)
            columns = columns.reshape(channels, height, bw).transpose(1, 0, 2).reshape(height, channels * bw)
            box = np.real(self.inv_y @ columns).astype(np.float32)  # (bh, C bw)
            return box.reshape(-1, channels, bw).transpose(1, 0, 2)
        rows = np.matmul(self.inv_y, spectrum)  # (C, bh, W') complex
        channels, bh, half = rows.shape
        return (rows.view(np.float32).reshape(channels * bh, 2 * half) @ self.inv_x_real).reshape(channels, bh, -1)

    def forward(self, box_values: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(C, H, W//2+1) complex64: rfft2 of the signal equal to box_values on the box, 0 elsewhere."""
        values = np.ascontiguousarray(box_values, dtype=np.float32)
        channels, bh, bw = values.shape
        half = self.fwd_x.shape[1]
        if not self.forward_rows_first:
            rows = (values.reshape(channels * bh, bw) @ self.fwd_x_of_real).view(np.complex64)
            return np.matmul(self.fwd_y, rows.reshape(channels, bh, half), out=out)
        height = self.fwd_y.shape[0]
        # one product for all channels: (2H, bh) @ (bh, C bw), real parts then imaginary parts
        columns = self.fwd_y_real @ values.transpose(1, 0, 2).reshape(bh, channels * bw)
        pairs = columns.reshape(2, height, channels, bw).transpose(2, 1, 0, 3).reshape(channels * height, 2 * bw)
        spectrum = (pairs @ self.fwd_x_of_pair).view(np.complex64).reshape(channels, height, half)
        if out is None:
            return spectrum
        out[...] = spectrum
        return out


def _frozen(matrix: np.ndarray) -> np.ndarray:
    """`matrix` made read-only: `_box_dft` hands one `_BoxDft` to every solve with its box."""
    matrix = np.ascontiguousarray(matrix)
    matrix.flags.writeable = False
    return matrix


@functools.lru_cache(maxsize=32)
def _box_dft(shape_hw: tuple[int, int], box: tuple[int, int, int, int]) -> _BoxDft:
    """The `_BoxDft` of a box, built once: a track keeps its box over many frames, and building its matrices
    costs about 1 M aarch64 instructions, 1.5 % of a tracked frame."""
    return _BoxDft(shape_hw, box)


def strcf_objective(
    filter_f: np.ndarray,
    sample_f: np.ndarray,
    label_f: np.ndarray,
    reg_window: np.ndarray,
    previous_f: np.ndarray | None,
    *,
    lam: float,
    mu: float,
) -> float:
    """E(f) of `admm_solve` (same units), evaluated on a filter spectrum (for tests and checks)."""
    shape_hw = reg_window.shape
    weights = fourier.half_spectrum_weights(shape_hw)[None, :]
    residual = response_spectrum(filter_f, sample_f) - label_f
    data = 0.5 * float(np.sum(weights * np.abs(residual) ** 2))
    spatial = fourier.irfft2(filter_f, shape_hw)
    n = float(shape_hw[0] * shape_hw[1])
    reg = 0.5 * lam * n * float(np.sum((reg_window[None] * spatial) ** 2))
    temporal = 0.0
    if previous_f is not None and mu > 0:
        temporal = 0.5 * mu * n * float(np.sum(weights[None] * np.abs(filter_f - previous_f) ** 2))
    return data + reg + temporal
