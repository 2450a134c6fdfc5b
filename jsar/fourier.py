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


def rfft2_channels_last(x: np.ndarray) -> np.ndarray:
    """`rfft2` of a channels-last stack: (M, H, W, C) float32 -> (M, H, W//2+1, C) complex64, over H and W.
    The same numbers as rfft2 of its channels-first copy, without making that copy."""
    return sfft.rfft2(x, axes=(1, 2), workers=1)


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


class Interpolant:
    """Fourier interpolant of a real (H, W) signal given by its half spectrum (MATLAB scaling).

    `derivatives(y, x)` -> (d/dy, d/dx, d2/dy2, d2/dx2, d2/dydx) at (y, x) cells of the
    trigonometric polynomial through the samples (Nyquist terms taken as cosines, so it stays
    real); the per-signal work is done once in the constructor.
    """

    def __init__(self, spectrum: np.ndarray, shape_hw: tuple[int, int]):
        height, width = shape_hw
        ky, kx = frequencies(shape_hw)
        self.wy = 2.0 * np.pi * ky / height
        self.wx = 2.0 * np.pi * kx / width
        self.weights = half_spectrum_weights(shape_hw)
        self.a = spectrum.astype(np.complex128) / (height * width)

    def value(self, y: float, x: float) -> float:
        """Interpolated value at (y, x) cells."""
        ey = np.exp(1j * self.wy * y)
        ex = np.exp(1j * self.wx * x) * self.weights
        return float(np.real(ey @ (self.a @ ex)))

    def derivatives(self, y: float, x: float) -> tuple[float, float, float, float, float]:
        """(dy, dx, dyy, dxx, dxy) of the interpolant at (y, x) cells."""
        ey = np.exp(1j * self.wy * y)
        ex = np.exp(1j * self.wx * x) * self.weights
        basis_x = np.stack([ex, 1j * self.wx * ex, -(self.wx**2) * ex], axis=1)  # (W', 3)
        ax = self.a @ basis_x  # (H, 3): a.ex, a.ex', a.ex''
        basis_y = np.stack([ey, 1j * self.wy * ey, -(self.wy**2) * ey], axis=0)  # (3, H)
        m = np.real(basis_y @ ax)  # m[i, j] = d^i/dy^i d^j/dx^j
        return float(m[1, 0]), float(m[0, 1]), float(m[2, 0]), float(m[0, 2]), float(m[1, 1])
