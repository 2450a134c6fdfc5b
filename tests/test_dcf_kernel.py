"""The compiled ADMM iteration (kernels.strcf_f_step) against admm_solve's numpy reference (kernel=False)."""
from __future__ import annotations

import numpy as np
import pytest

from jsar import dcf, fourier
from jsar.features._native import kernels

SOLVER = dict(lam=1e-2, mu=16.0, penalty_init=1.0, penalty_growth=10.0, penalty_max=1e4)


def _spectra(rng: np.random.Generator, channels: int, shape_hw: tuple[int, int]) -> np.ndarray:
    """(C, H, W//2+1) complex64 spectrum of random float32 channels."""
    return fourier.rfft2(rng.standard_normal((channels, *shape_hw)).astype(np.float32))


def _relative_error(result: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(result - reference) / np.linalg.norm(reference))


def _numpy_multiplies_with_fma() -> bool:
    """Whether numpy's complex64 product is (fma(ar, br, -(ai bi)), fma(ar, bi, ai br)), as on x86-64 with AVX2/FMA:
    then the kernel, which rounds as that, must give numpy's numbers to the bit."""
    rng = np.random.default_rng(0)
    a, b = (rng.standard_normal((2, 4096)).astype(np.float32) for _ in range(2))
    product = (a[0] + 1j * a[1]).astype(np.complex64) * (b[0] + 1j * b[1]).astype(np.complex64)
    wide = [v.astype(np.float64) for v in (a[0], a[1], b[0], b[1])]
    real = (wide[0] * wide[2] - (a[1] * b[1]).astype(np.float64)).astype(np.float32)
    imag = (wide[0] * wide[3] + (a[1] * b[0]).astype(np.float64)).astype(np.float32)
    return bool(np.array_equal(product.real, real) and np.array_equal(product.imag, imag))


@pytest.mark.parametrize("channels, shape_hw, box_cells", [
    (42, (50, 50), (10.0, 12.0)),  # the tracker's stack: fHOG 31 + colour names 10 + grey 1
    (7, (31, 27), (6.0, 5.0)),     # odd sizes: odd half-spectrum width
    (3, (20, 34), (4.0, 9.0)),     # even width, few channels
])
@pytest.mark.parametrize("with_previous", [False, True])
@pytest.mark.parametrize("box_transforms", [None, False])
@pytest.mark.parametrize("iterations", [1, 2, 4])
def test_compiled_iterations_equal_the_numpy_reference(channels, shape_hw, box_cells, with_previous,
                                                       box_transforms, iterations):
    rng = np.random.default_rng(channels * 100 + iterations)
    sample_f = _spectra(rng, channels, shape_hw)
    label_f = fourier.rfft2(dcf.gaussian_label(shape_hw, 0.8))
    window = dcf.regularisation_window(shape_hw, box_cells, 1e-3, 1e5)
    previous_f = _spectra(rng, channels, shape_hw) * np.float32(1e-3) if with_previous else None
    reference = dcf.admm_solve(sample_f, label_f, window, previous_f, iterations=iterations,
                               box_transforms=box_transforms, kernel=False, **SOLVER)
    compiled = dcf.admm_solve(sample_f, label_f, window, previous_f, iterations=iterations,
                              box_transforms=box_transforms, **SOLVER)
    assert compiled.dtype == np.complex64 and compiled.shape == reference.shape
    assert _relative_error(compiled, reference) < 1e-5
    if _numpy_multiplies_with_fma():  # the tracker's results must not move with the kernel
        np.testing.assert_array_equal(compiled, reference)


def test_the_box_path_is_taken_and_agrees_when_forced():
    rng = np.random.default_rng(3)
    shape_hw = (50, 50)
    sample_f = _spectra(rng, 5, shape_hw)
    label_f = fourier.rfft2(dcf.gaussian_label(shape_hw, 0.8))
    window = dcf.regularisation_window(shape_hw, (8.0, 11.0), 1e-3, 1e5)
    previous_f = _spectra(rng, 5, shape_hw) * np.float32(1e-3)
    reference = dcf.admm_solve(sample_f, label_f, window, previous_f, iterations=4, box_transforms=True,
                               kernel=False, **SOLVER)
    compiled = dcf.admm_solve(sample_f, label_f, window, previous_f, iterations=4, box_transforms=True,
                              kernel=True, **SOLVER)
    assert _relative_error(compiled, reference) < 1e-5


def test_compiled_filters_stay_with_the_reference_over_a_sequence_of_updates():
    """Each frame's filter is the next frame's temporal anchor: rounding differences must not grow."""
    rng = np.random.default_rng(5)
    shape_hw = (50, 50)
    label_f = fourier.rfft2(dcf.gaussian_label(shape_hw, 0.8))
    window = dcf.regularisation_window(shape_hw, (10.0, 10.0), 1e-3, 1e5)
    base = _spectra(rng, 12, shape_hw)
    reference = compiled = None
    for _ in range(6):
        sample_f = base + _spectra(rng, 12, shape_hw) * np.float32(0.3)
        reference = dcf.admm_solve(sample_f, label_f, window, reference, iterations=4, kernel=False, **SOLVER)
        compiled = dcf.admm_solve(sample_f, label_f, window, compiled, iterations=4, **SOLVER)
        assert _relative_error(compiled, reference) < 1e-5


def _kernel_arguments(channels: int = 2, frequencies: int = 6) -> list:
    """A valid strcf_f_step call (first iteration, no previous filter) on zero buffers."""
    spectrum = lambda: np.zeros((channels, frequencies), np.complex64)  # noqa: E731
    return [spectrum(), np.zeros(frequencies, np.complex64), None, spectrum(), np.zeros(frequencies, np.float32),
            spectrum(), spectrum(), spectrum(), spectrum(), channels, frequencies, 0.0, 0.0, 1.0, 0.0, 1.0,
            True, False]


def test_kernel_accepts_its_valid_call():
    kernels.strcf_f_step(*_kernel_arguments())


@pytest.mark.parametrize("index, bad, error, name", [
    (0, np.zeros((2, 6), np.complex128), TypeError, "x"),
    (4, np.zeros(6, np.float64), TypeError, "sxx"),
    (1, np.zeros(6, np.float32), TypeError, "label"),
    (2, np.zeros((2, 5), np.complex64), ValueError, "prev"),
    (5, np.zeros((2, 5), np.complex64), ValueError, "q"),
    (8, np.zeros((1, 6), np.complex64), ValueError, "numerator"),
])
def test_kernel_rejects_wrong_types_and_undersized_buffers_naming_them(index, bad, error, name):
    args = _kernel_arguments()
    args[index] = bad
    with pytest.raises(error, match=f"^{name}:"):
        kernels.strcf_f_step(*args)


def test_kernel_rejects_an_output_that_is_also_an_input():
    args = _kernel_arguments()
    args[5] = args[0]  # q written over the sample
    with pytest.raises(ValueError, match="q and x"):
        kernels.strcf_f_step(*args)
