"""The size filter's compiled grid kernels (kernels.grid_spectrum / grid_train / grid_response) against their
numpy specifications in jsar/tracking/size_filter.py, and their argument checks."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft

from jsar.config import JsarParams
from jsar.features._native import kernels
from jsar.tracking.size_filter import (SizeFilter, dsst_response_spectrum_reference, dsst_train_reference,
                                       grid_spectrum_reference, grid_window, half_twiddles)


def _relative_error(result: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(result - reference).max() / np.abs(reference).max())


def _spectrum(sample: np.ndarray, window: np.ndarray) -> np.ndarray:
    n_s, n_a, channels = sample.shape
    out = np.empty((n_s, n_a // 2 + 1, channels), np.complex64)
    scratch = np.empty((n_s, n_a // 2 + 1, 2, channels), np.float32)
    kernels.grid_spectrum(sample, window, *half_twiddles(n_a), *half_twiddles(n_s), scratch, out, n_s, n_a,
                          channels)
    return out


# The tracker's grid (13 x 13, channels a multiple of the 8-lane block and not), even sides, a single cell.
@pytest.mark.parametrize("grid, channels", [((13, 13), 930), ((13, 13), 37), ((12, 9), 8), ((8, 14), 3), ((1, 1), 5)])
def test_grid_spectrum_equals_the_numpy_reference_and_rfft2(grid, channels):
    rng = np.random.default_rng(channels)
    sample = rng.standard_normal((*grid, channels)).astype(np.float32)
    window = rng.uniform(0.1, 1.0, grid).astype(np.float32)
    result = _spectrum(sample, window)
    assert _relative_error(result, grid_spectrum_reference(sample, window)) < 1e-5
    expected = scipy.fft.rfft2(sample * window[:, :, None], axes=(0, 1))
    assert _relative_error(result, expected) < 1e-5


def test_the_filter_trains_and_responds_as_the_numpy_reference_over_frames():
    params = JsarParams()
    sf = SizeFilter(params, (20.0, 60.0))
    rng = np.random.default_rng(3)
    numerator = denominator = None
    for _ in range(4):
        sample_f = sf.spectrum(rng.standard_normal((13, 13, 930)).astype(np.float32))
        numerator, denominator = dsst_train_reference(numerator, denominator, sf.label_f, sample_f,
                                                      params.size_learning_rate)
        sf.train(sample_f)
        assert _relative_error(sf.numerator, numerator) < 1e-5
        assert _relative_error(sf.denominator, denominator) < 1e-5
    probe = sf.spectrum(rng.standard_normal((13, 13, 930)).astype(np.float32))
    expected = scipy.fft.irfft2(dsst_response_spectrum_reference(numerator, denominator, probe, params.size_lambda),
                                s=(13, 13))
    assert _relative_error(sf.response(probe), expected) < 1e-4


def test_the_grid_window_is_applied_and_can_be_off():
    sample = np.random.default_rng(0).standard_normal((13, 13, 16)).astype(np.float32)
    on = SizeFilter(JsarParams(size_grid_window=True), (20.0, 20.0)).spectrum(sample)
    off_params = JsarParams(size_grid_window=False)
    off = SizeFilter(off_params, (20.0, 20.0)).spectrum(sample)
    assert np.all(grid_window(off_params) == 1.0)
    assert _relative_error(off, scipy.fft.rfft2(sample, axes=(0, 1))) < 1e-5
    assert _relative_error(on, off) > 0.1


def test_grid_kernels_refuse_wrong_buffers():
    sample = np.zeros((13, 13, 8), np.float32)
    window = np.ones((13, 13), np.float32)
    twiddles = (*half_twiddles(13), *half_twiddles(13))
    out = np.empty((13, 7, 8), np.complex64)
    scratch = np.empty((13, 7, 2, 8), np.float32)
    with pytest.raises(ValueError, match="x: buffer holds"):
        kernels.grid_spectrum(sample[:12], window, *twiddles, scratch, out, 13, 13, 8)
    with pytest.raises(TypeError, match="out: expected complex64"):
        kernels.grid_spectrum(sample, window, *twiddles, scratch, out.view(np.float32), 13, 13, 8)
    with pytest.raises(ValueError, match="distinct"):
        kernels.grid_spectrum(scratch, window, *twiddles, scratch, out, 13, 13, 8)
    with pytest.raises(ValueError, match="at most 64"):
        kernels.grid_spectrum(sample, window, *twiddles, scratch, out, 65, 1, 8)
    spectrum = np.zeros((91, 8), np.complex64)
    label = np.zeros(91, np.complex64)
    with pytest.raises(ValueError, match="distinct"):
        kernels.grid_train(label, spectrum, spectrum, np.zeros(91, np.float32), 0.1, False, 91, 8)
    with pytest.raises(ValueError, match="out: buffer holds"):
        kernels.grid_response(spectrum, spectrum, np.zeros(91, np.float32), 0.01, np.zeros(90, np.complex64), 91, 8)
