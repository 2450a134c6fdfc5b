"""The decision filter's window kernels (kernels.window_channels_last, kernels.response_spectra) against their numpy
references, to the bit: a lost frame's decisions are thresholds on these numbers."""
from __future__ import annotations

import numpy as np
import pytest

from jsar import dcf, fourier


def _windows(rng: np.random.Generator, m: int, shape_hw: tuple[int, int], channels: int) -> np.ndarray:
    """(M, H, W, C) float32 feature windows with the value range of real ones (fHOG, colour names, grey)."""
    return rng.uniform(-0.5, 0.6, (m, *shape_hw, channels)).astype(np.float32)


@pytest.mark.parametrize("m, shape_hw, channels", [(1, (50, 50), 42), (7, (50, 50), 42), (3, (20, 31), 42),
                                                   (2, (13, 8), 11), (5, (44, 44), 1)])
def test_the_window_kernels_give_the_references_numbers_to_the_bit(m, shape_hw, channels):
    rng = np.random.default_rng(m * 100 + channels)
    windows = _windows(rng, m, shape_hw, channels)
    cos_window = dcf.hann_window(shape_hw)
    windowed = dcf.windowed_channels_last(windows, cos_window)
    assert np.array_equal(windowed, windows * cos_window[None, :, :, None])
    spectra = fourier.rfft2_channels_last(windowed)
    filter_f = fourier.rfft2(rng.standard_normal((channels, *shape_hw)).astype(np.float32) * 1e-2)
    result = dcf.response_spectra(filter_f, spectra)
    reference = dcf.response_spectra_reference(filter_f, spectra)
    assert result.dtype == reference.dtype == np.complex64 and result.shape == reference.shape == (m, shape_hw[0],
                                                                                                     shape_hw[1] // 2 + 1)
    assert np.array_equal(result.view(np.uint32), reference.view(np.uint32))  # signed zeros too


@pytest.mark.parametrize("chunk_bytes", [1, 900_000, 2 << 20, 1 << 40])
def test_the_window_chain_in_chunks_gives_one_batchs_numbers_to_the_bit(chunk_bytes):
    """A lost frame's windows go through window -> FFT -> correlation a few at a time (cache-sized chunks): the
    numbers must be those of the whole batch at once, whatever the chunk (one window, two, all)."""
    rng = np.random.default_rng(7)
    windows = _windows(rng, 9, (50, 50), 42)
    cos_window = dcf.hann_window((50, 50))
    filter_f = fourier.rfft2(rng.standard_normal((42, 50, 50)).astype(np.float32) * 1e-2)
    batch = dcf.response_spectra(filter_f, fourier.rfft2_channels_last(dcf.windowed_channels_last(windows, cos_window)))
    chunked = dcf.window_response_spectra(filter_f, list(windows), cos_window, chunk_bytes)
    assert chunked.shape == batch.shape and chunked.dtype == np.complex64
    assert np.array_equal(chunked.view(np.uint32), batch.view(np.uint32))
    # Views into a larger feature map (the upright windows' case) give the same numbers.
    feature_map = np.zeros((60, 60 * 9, 42), np.float32)
    views = []
    for k, window in enumerate(windows):
        feature_map[5:55, 60 * k + 3:60 * k + 53] = window
        views.append(feature_map[5:55, 60 * k + 3:60 * k + 53])
    assert np.array_equal(dcf.window_response_spectra(filter_f, views, cos_window, chunk_bytes).view(np.uint32),
                          batch.view(np.uint32))


def test_a_zero_spectrum_gives_positive_zeros_as_numpy_does():
    """numpy adds each sum to a zeroed output, so a sum of -0.0 terms comes out +0.0: the kernel too."""
    filter_f = np.zeros((3, 4, 3), np.complex64)
    filter_f.real[...] = -1.0
    spectra = np.zeros((2, 4, 3, 3), np.complex64)
    spectra.real[...] = 0.0
    spectra.imag[...] = -0.0
    assert np.array_equal(dcf.response_spectra(filter_f, spectra).view(np.uint32),
                          dcf.response_spectra_reference(filter_f, spectra).view(np.uint32))


def test_the_window_kernels_refuse_mismatched_shapes_and_types_naming_them():
    windows = np.zeros((2, 5, 6, 3), np.float32)
    with pytest.raises(ValueError, match="cos_window"):
        dcf.windowed_channels_last(windows, np.ones((6, 5), np.float32))
    with pytest.raises(ValueError, match="spectra"):
        dcf.response_spectra(np.zeros((3, 5, 4), np.complex64), np.zeros((2, 5, 4, 2), np.complex64))
    from jsar.features._native import kernels
    with pytest.raises(TypeError, match="spectra"):
        kernels.response_spectra(np.zeros((3, 5, 4), np.complex64), np.zeros((2, 5, 4, 3), np.float32),
                                 np.zeros((2, 5, 4), np.complex64), 2, 20, 3)
    with pytest.raises(ValueError, match="out"):
        kernels.response_spectra(np.zeros((3, 5, 4), np.complex64), np.zeros((2, 5, 4, 3), np.complex64),
                                 np.zeros((1, 5, 4), np.complex64), 2, 20, 3)


def test_the_response_kernel_refuses_an_output_that_is_also_an_input():
    """The sums read every channel of a window before writing its output: an output on an input's memory would
    overwrite spectra still to be read."""
    from jsar.features._native import kernels
    spectra = np.zeros((2, 5, 4, 1), np.complex64)
    with pytest.raises(ValueError, match="distinct"):
        kernels.response_spectra(np.zeros((1, 5, 4), np.complex64), spectra, spectra, 2, 20, 1)
