"""Real 2-D FFT helpers in the MATLAB scaling convention, on channels-first stacks.

Convention (used everywhere in jsar): the forward DFT is unnormalised and the inverse is scaled
by 1/N (N = H*W), exactly like MATLAB's fft2/ifft2 and scipy's default norm="backward". Spectra
are half spectra from rfft2 over the last two axes: (..., H, W//2 + 1), complex64.
Single-threaded (workers=1): speed is measured on one thread.
"""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft


def rfft2(x: np.ndarray) -> np.ndarray:
    """Half spectrum over the last two axes: (..., H, W) float32 -> (..., H, W//2+1) complex64."""
    return sfft.rfft2(x, axes=(-2, -1), workers=1)


def irfft2(xf: np.ndarray, shape_hw: tuple[int, int]) -> np.ndarray:
    """Inverse of `rfft2` (scaled by 1/N): (..., H, W//2+1) -> (..., H, W) real."""
    return sfft.irfft2(xf, s=shape_hw, axes=(-2, -1), workers=1)


def frequencies(shape_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Integer frequencies of the half spectrum: ky (H,) in FFT order, kx (W//2+1,) = 0..W//2."""
    height, width = shape_hw
    return np.fft.fftfreq(height, 1.0 / height), np.arange(width // 2 + 1, dtype=np.float64)


def half_spectrum_weights(shape_hw: tuple[int, int]) -> np.ndarray:
    """(W//2+1,) weights so that sum over the full spectrum = sum over the half times weight.

    Column 0 and, for even W, the Nyquist column appear once in the full spectrum; the others
    stand for themselves and their conjugate mirror.
    """
    width = shape_hw[1]
    weights = np.full(width // 2 + 1, 2.0)
    weights[0] = 1.0
    if width % 2 == 0:
        weights[-1] = 1.0
    return weights


def shift_phase(shape_hw: tuple[int, int], dy: float, dx: float) -> np.ndarray:
    """(H, W//2+1) complex64 factor that moves signal content by (-dy, -dx) cells, circularly.

    Multiplying a half spectrum X by it gives the spectrum of x'(n) = x(n + d): the point that
    was at d lands at 0. Used to re-centre a detection sample on the found target position.
    """
    ky, kx = frequencies(shape_hw)
    height, width = shape_hw
    phase = 2.0 * np.pi * (ky[:, None] * (dy / height) + kx[None, :] * (dx / width))
    return np.exp(1j * phase).astype(np.complex64)


def interpolated_value_and_derivatives(
    spectrum: np.ndarray, shape_hw: tuple[int, int], y: float, x: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """Fourier-interpolated value, gradient (d/dy, d/dx) and 2x2 Hessian at (y, x) cells.

    `spectrum` is the (H, W//2+1) half spectrum of a real (H, W) signal in the MATLAB
    convention; the interpolant is the trigonometric polynomial through its samples
    (Nyquist terms taken as cosines, so it stays real).
    """
    height, width = shape_hw
    ky, kx = frequencies(shape_hw)
    wy = 2.0 * np.pi * ky / height
    wx = 2.0 * np.pi * kx / width
    ey = np.exp(1j * wy * y)
    ex = np.exp(1j * wx * x) * half_spectrum_weights(shape_hw)
    a = spectrum.astype(np.complex128) / (height * width)
    # Each term Re(ey_i * a_ij * ex_j); derivatives bring down i*w factors.
    ax = a @ ex
    ax_dx = a @ (1j * wx * ex)
    ax_dxx = a @ (-(wx**2) * ex)
    value = float(np.real(ey @ ax))
    dy = float(np.real((1j * wy * ey) @ ax))
    dx = float(np.real(ey @ ax_dx))
    dyy = float(np.real((-(wy**2) * ey) @ ax))
    dxx = float(np.real(ey @ ax_dxx))
    dxy = float(np.real((1j * wy * ey) @ ax_dx))
    return value, np.array([dy, dx]), np.array([[dyy, dxy], [dxy, dxx]])
