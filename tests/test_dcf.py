"""Correlation-filter math: conventions, the STRCF ADMM solve, responses and the sub-cell peak."""
from __future__ import annotations

import platform

import numpy as np
import pytest

from jsar import dcf, fourier
from jsar.config import JsarParams

SHAPE = (50, 50)


def _smooth_random_features(rng: np.random.Generator, channels: int, shape=SHAPE) -> np.ndarray:
    """Band-limited random channels (C, H, W) float32: smooth enough for sub-cell interpolation."""
    noise = rng.standard_normal((channels, *shape)).astype(np.float32)
    spec = fourier.rfft2(noise)
    ky, kx = fourier.frequencies(shape)
    lowpass = np.exp(-0.5 * (ky[:, None] ** 2 + kx[None, :] ** 2) / 4.0**2)
    return fourier.irfft2(spec * lowpass, shape).astype(np.float32)


def _solve(sample_f, label_f, window, previous_f=None, iterations=4, lam=1e-2, mu=16.0):
    return dcf.admm_solve(
        sample_f, label_f, window, previous_f, lam=lam, mu=mu, iterations=iterations,
        penalty_init=1.0, penalty_growth=10.0, penalty_max=1e4)


def test_label_peak_is_at_origin_and_wraps_symmetrically():
    label = dcf.gaussian_label((8, 10), sigma=1.5)
    assert label.dtype == np.float32
    assert np.unravel_index(np.argmax(label), label.shape) == (0, 0)
    assert label[0, 0] == pytest.approx(1.0)
    assert label[1, 0] == pytest.approx(label[-1, 0])  # circular: offset +1 and -1 are equal
    assert label[0, 3] == pytest.approx(label[0, -3])
    assert label[0, 1] == pytest.approx(np.exp(-0.5 / 1.5**2), rel=1e-5)


def test_hann_window_has_no_zero_border_and_peaks_in_the_middle():
    window = dcf.hann_window((6, 9))
    assert window.min() > 0
    assert window[2, 4] == pytest.approx(window.max()) and window[3, 4] == pytest.approx(window.max())
    np.testing.assert_allclose(window, window[::-1, ::-1], rtol=1e-6)


def test_regularisation_window_box_is_centred_with_floored_size():
    window = dcf.regularisation_window((50, 50), (10.7, 6.2), inside=1e-3, outside=1e5)
    inside = window == np.float32(1e-3)
    rows, cols = np.nonzero(inside)
    assert inside.sum() == 10 * 6
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (20, 29, 22, 27)
    assert np.all(window[~inside] == np.float32(1e5))


def test_response_is_the_circular_correlation_in_matlab_scaling():
    """IFFT(sum conj(F) X) with unnormalised forward / 1/N inverse equals sum_n f(n) x(n + t)."""
    rng = np.random.default_rng(0)
    f = rng.standard_normal((3, 6, 8)).astype(np.float32)
    x = rng.standard_normal((3, 6, 8)).astype(np.float32)
    resp = dcf.response(fourier.rfft2(f), fourier.rfft2(x), (6, 8))
    for t in [(0, 0), (1, 3), (5, 7)]:
        expected = np.sum(f * np.roll(x, shift=(-t[0], -t[1]), axis=(1, 2)))
        assert resp[t] == pytest.approx(expected, rel=1e-4, abs=1e-4)
    # Forward unnormalised: the DC term of a constant 1 map is N, and the inverse divides by N.
    assert fourier.rfft2(np.ones((6, 8), np.float32))[0, 0] == pytest.approx(48.0)


def test_channels_last_rfft2_gives_the_channels_first_spectra_exactly():
    """rfft2_channels_last (M, H, W, C) is rfft2 of the channels-first copy (M, C, H, W): the decision filter's
    windows use it. On x86-64, where the results are measured, bit for bit (the tracker's results must not depend
    on the layout); on aarch64 pocketfft's vector paths differ by the last bit on about 1 % of the values."""
    rng = np.random.default_rng(2)
    stack = rng.standard_normal((3, 10, 12, 5)).astype(np.float32)
    last = fourier.rfft2_channels_last(stack)
    assert last.shape == (3, 10, 7, 5) and last.dtype == np.complex64
    channels_first = np.ascontiguousarray(np.moveaxis(stack, -1, 1))
    expected = fourier.rfft2(channels_first)
    if platform.machine() in ("x86_64", "AMD64"):
        np.testing.assert_array_equal(np.moveaxis(last, -1, 1), expected)
    else:
        np.testing.assert_allclose(np.moveaxis(last, -1, 1), expected, rtol=0, atol=1e-6 * np.abs(expected).max())


def test_peak_threshold_convention_impulse_filter_reproduces_sample_values():
    """A unit impulse filter returns the sample itself: peak thresholds are in feature units."""
    rng = np.random.default_rng(1)
    impulse = np.zeros((1, 10, 10), np.float32)
    impulse[0, 0, 0] = 1.0
    sample = rng.uniform(0, 0.02, (1, 10, 10)).astype(np.float32)
    resp = dcf.response(fourier.rfft2(impulse), fourier.rfft2(sample), (10, 10))
    np.testing.assert_allclose(resp, sample[0], atol=1e-7)


def test_filter_solve_recovers_a_known_circular_shift():
    rng = np.random.default_rng(2)
    sample = 5.0 * _smooth_random_features(rng, 8)  # data term dominates the N-scaled penalty
    label_f = fourier.rfft2(dcf.gaussian_label(SHAPE, 0.5))
    window = dcf.regularisation_window(SHAPE, (12, 12), 1e-3, 1e5)
    filt = _solve(fourier.rfft2(sample), label_f, window)
    for shift in [(0, 0), (3, -5), (-7, 2)]:
        moved = np.roll(sample, shift=shift, axis=(1, 2))
        resp = dcf.response(filt, fourier.rfft2(moved), SHAPE)
        dy, dx, _ = dcf.subpixel_peak(resp, fourier.rfft2(resp), iterations=5)
        assert (dy, dx) == pytest.approx(shift, abs=0.05)


def test_subpixel_peak_finds_a_fractional_shift_with_the_right_sign():
    rng = np.random.default_rng(3)
    sample = _smooth_random_features(rng, 8)
    sample_f = fourier.rfft2(sample)
    label_f = fourier.rfft2(dcf.gaussian_label(SHAPE, 1.5))
    window = dcf.regularisation_window(SHAPE, (14, 14), 1e-3, 1e5)
    filt = _solve(sample_f, label_f, window)
    true_shift = (2.3, -1.6)  # target moved 2.3 cells down, 1.6 cells left
    moved_f = sample_f * fourier.shift_phase(SHAPE, -true_shift[0], -true_shift[1])[None]
    resp = dcf.response(filt, moved_f, SHAPE)
    dy, dx, _ = dcf.subpixel_peak(resp, fourier.rfft2(resp), iterations=5)
    assert dy == pytest.approx(true_shift[0], abs=0.1)
    assert dx == pytest.approx(true_shift[1], abs=0.1)


def test_shift_phase_recentres_a_sample_on_the_found_displacement():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((2, 12, 10)).astype(np.float32)
    moved = np.roll(x, shift=(3, -2), axis=(1, 2))  # content moved by (+3, -2)
    recentred = fourier.irfft2(fourier.rfft2(moved) * fourier.shift_phase((12, 10), 3, -2), (12, 10))
    np.testing.assert_allclose(recentred, x, atol=1e-5)


def test_admm_decreases_the_strcf_objective():
    rng = np.random.default_rng(5)
    sample_f = fourier.rfft2(_smooth_random_features(rng, 6))
    previous_f = fourier.rfft2(_smooth_random_features(rng, 6)) * np.float32(1e-3)
    label_f = fourier.rfft2(dcf.gaussian_label(SHAPE, 1.0))
    window = dcf.regularisation_window(SHAPE, (10, 10), 1e-3, 1e5)
    kwargs = dict(lam=1e-2, mu=16.0)

    def objective(filt):
        # Evaluate on the filter projected to its constrained support (the ADMM g variable's
        # feasible set); the residual outside it is what the growing penalty removes.
        spatial = fourier.irfft2(filt, SHAPE) * (window < 1)[None]
        return dcf.strcf_objective(fourier.rfft2(spatial.astype(np.float32)), sample_f, label_f,
                                   window, previous_f, **kwargs)

    zero = dcf.strcf_objective(np.zeros_like(sample_f), sample_f, label_f, window, previous_f, **kwargs)
    values = [objective(_solve(sample_f, label_f, window, previous_f, iterations=k)) for k in (1, 2, 4, 8)]
    assert values[0] < zero
    assert values[-1] < values[0]
    assert values[2] <= values[1] * 1.001
    assert values[3] <= values[2] * 1.001


def test_temporal_term_pulls_the_filter_towards_the_previous_one():
    rng = np.random.default_rng(6)
    sample_f = fourier.rfft2(_smooth_random_features(rng, 4))
    label_f = fourier.rfft2(dcf.gaussian_label(SHAPE, 1.0))
    window = dcf.regularisation_window(SHAPE, (10, 10), 1e-3, 1e5)
    previous = _solve(sample_f, label_f, window)
    other_f = fourier.rfft2(_smooth_random_features(rng, 4))
    free = _solve(other_f, label_f, window, previous, mu=0.0)
    tied = _solve(other_f, label_f, window, previous, mu=16.0)
    assert np.linalg.norm(tied - previous) < np.linalg.norm(free - previous)


def test_params_defaults_and_overrides():
    params = JsarParams()
    assert (params.num_scales, params.num_aspects, params.scale_step, params.aspect_step) == (13, 13, 1.03, 1.02)
    assert params.admm_lambda == 1e-2 and JsarParams.jsar_re().admm_lambda == 1.0
    assert params.with_overrides(scale_step=1.05).scale_step == 1.05
    with pytest.raises(ValueError, match="unknown JsarParams key 'scale_stp'"):
        params.with_overrides(scale_stp=1.05)
    with pytest.raises(ValueError, match="num_scales must be odd"):
        params.with_overrides(num_scales=12)
    with pytest.raises(ValueError, match="scale_step"):
        params.with_overrides(scale_step="big")


def test_interpolant_matches_samples_and_numeric_derivatives():
    rng = np.random.default_rng(8)
    signal = _smooth_random_features(rng, 1, (12, 10))[0]
    spec = fourier.rfft2(signal)
    interp = fourier.Interpolant(spec, (12, 10))
    assert interp.value(3.0, 4.0) == pytest.approx(float(signal[3, 4]), abs=1e-5)
    y, x, eps = 2.3, 6.7, 1e-4
    dy, dx, dyy, dxx, dxy = interp.derivatives(y, x)
    assert dy == pytest.approx((interp.value(y + eps, x) - interp.value(y - eps, x)) / (2 * eps), rel=1e-3, abs=1e-5)
    assert dx == pytest.approx((interp.value(y, x + eps) - interp.value(y, x - eps)) / (2 * eps), rel=1e-3, abs=1e-5)
    num_dxy = (interp.value(y + eps, x + eps) - interp.value(y + eps, x - eps)
               - interp.value(y - eps, x + eps) + interp.value(y - eps, x - eps)) / (4 * eps**2)
    assert dxy == pytest.approx(num_dxy, rel=1e-2, abs=1e-3)
    num_dyy = (interp.value(y + eps, x) - 2 * interp.value(y, x) + interp.value(y - eps, x)) / eps**2
    assert dyy == pytest.approx(num_dyy, rel=1e-2, abs=1e-3)


@pytest.mark.parametrize("box_cells", [(10.0, 10.0), (4.0, 17.0), (13.0, 3.0)])
def test_box_restricted_g_step_equals_the_full_fft_g_step(box_cells):
    rng = np.random.default_rng(9)
    sample_f = fourier.rfft2(_smooth_random_features(rng, 5))
    previous_f = fourier.rfft2(_smooth_random_features(rng, 5)) * np.float32(1e-3)
    label_f = fourier.rfft2(dcf.gaussian_label(SHAPE, 0.6))
    window = dcf.regularisation_window(SHAPE, box_cells, 1e-3, 1e5)
    results = [dcf.admm_solve(sample_f, label_f, window, previous_f, lam=1e-2, mu=16.0, iterations=4,
                              penalty_init=1.0, penalty_growth=10.0, penalty_max=1e4, box_transforms=flag)
               for flag in (False, True)]
    scale = np.abs(results[0]).max()
    np.testing.assert_allclose(results[1], results[0], atol=2e-4 * scale)


def test_box_transforms_require_a_box_window():
    window = dcf.regularisation_window(SHAPE, (10.0, 10.0), 1e-3, 1e5)
    window[0, 0] = 5.0
    zeros = np.zeros((2, 50, 26), np.complex64)
    with pytest.raises(ValueError, match="rectangular"):
        dcf.admm_solve(zeros, zeros[0], window, None, lam=1e-2, mu=16.0, iterations=2, penalty_init=1.0,
                       penalty_growth=10.0, penalty_max=1e4, box_transforms=True)


@pytest.mark.parametrize("box", [(16, 33, 22, 27), (20, 29, 20, 30), (22, 27, 16, 33), (0, 1, 0, 50)])
@pytest.mark.parametrize("rows_first", [False, True])
def test_box_transforms_equal_the_full_ffts_in_either_order(box, rows_first):
    """Both orders of each direction (the cost model picks one per box) are irfft2 / rfft2 on the box."""
    rng = np.random.default_rng(sum(box))
    spectrum = fourier.rfft2(rng.standard_normal((4, *SHAPE)).astype(np.float32))
    partial = dcf._BoxDft(SHAPE, box)
    partial.inverse_rows_first = partial.forward_rows_first = rows_first
    r0, r1, c0, c1 = box
    spatial = fourier.irfft2(spectrum, SHAPE)
    np.testing.assert_allclose(partial.inverse(spectrum), spatial[:, r0:r1, c0:c1], atol=1e-5 * np.abs(spatial).max())
    values = rng.standard_normal((4, r1 - r0, c1 - c0)).astype(np.float32)
    padded = np.zeros((4, *SHAPE), np.float32)
    padded[:, r0:r1, c0:c1] = values
    expected = fourier.rfft2(padded)
    out = np.empty_like(expected)
    assert partial.forward(values, out=out) is out
    np.testing.assert_allclose(out, expected, atol=1e-5 * np.abs(expected).max())


def test_the_box_transforms_take_the_cheaper_order_for_the_box_shape():
    assert not dcf._BoxDft((50, 50), (16, 33, 22, 27)).inverse_rows_first  # tall: columns first
    assert dcf._BoxDft((50, 50), (16, 33, 22, 27)).forward_rows_first
    assert dcf._BoxDft((50, 50), (22, 27, 16, 33)).inverse_rows_first  # wide: rows first
    assert not dcf._BoxDft((50, 50), (22, 27, 16, 33)).forward_rows_first
