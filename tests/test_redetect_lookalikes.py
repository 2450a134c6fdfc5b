"""The look-alike check's pure parts: descriptors, secondary peaks of a response, the bank's margin."""
from __future__ import annotations

import math

import numpy as np
import pytest

from jsar.features.colour import derived_colour_table
from jsar.redetect.lookalikes import LookalikeBank, appearance_descriptor, nearest_similarity, secondary_peaks
from jsar.redetect.params import RedetectParams


def _scene() -> np.ndarray:
    rng = np.random.default_rng(5)
    frame = rng.integers(90, 130, (120, 200, 3), dtype=np.uint8)
    frame[40:64, 30:54] = (40, 60, 220)  # a red box with a yellow centre and a dark bar: the target
    frame[46:58, 36:48] = (240, 240, 40)
    frame[50:54, 30:54] = (20, 20, 20)
    frame[40:64, 120:144] = (40, 60, 220)  # the same colours, the bar upright: a look-alike
    frame[46:58, 126:138] = (240, 240, 40)
    frame[40:64, 130:134] = (20, 20, 20)
    return frame


def test_descriptor_is_a_unit_vector_and_ignores_a_uniform_change_of_light():
    frame, table = _scene(), derived_colour_table()
    target = appearance_descriptor(frame, (30, 40, 24, 24), table)
    assert target.shape == (6 * 6 * 42,) and math.isclose(float(np.linalg.norm(target)), 1.0, rel_tol=1e-5)
    brighter = appearance_descriptor(np.clip(frame.astype(int) + 20, 0, 255).astype(np.uint8), (30, 40, 24, 24), table)
    look_alike = appearance_descriptor(frame, (120, 40, 24, 24), table)
    assert float(target @ brighter) > 0.9
    assert float(target @ look_alike) < float(target @ brighter) - 0.2  # its layout differs
    grey = appearance_descriptor(frame[..., 1].copy(), (30, 40, 24, 24), None)
    assert grey.shape == (6 * 6 * 32,)


def _response(peaks: dict[tuple[int, int], float], shape: tuple[int, int] = (40, 40)) -> np.ndarray:
    """A wrapped response map (zero displacement at [0, 0]) with Gaussian bumps at (dy, dx) cells."""
    ys = np.fft.fftfreq(shape[0], 1.0 / shape[0])[:, None]
    xs = np.fft.fftfreq(shape[1], 1.0 / shape[1])[None, :]
    response = np.zeros(shape)
    for (dy, dx), value in peaks.items():
        response += value * np.exp(-((ys - dy) ** 2 + (xs - dx) ** 2) / 2.0)
    return response


def test_secondary_peaks_are_the_local_maxima_a_target_size_off_the_main_peak_strongest_first():
    response = _response({(2, 1): 1.0, (-12, 10): 0.6, (10, -14): 0.45, (2, 4): 0.7, (15, 15): 0.2})
    found = secondary_peaks(response, target_cells=(6.0, 6.0), min_fraction=0.3, max_peaks=5)
    # (2, 4) lies within a target size of the main peak (a part of the target); (15, 15) is too weak.
    assert [(round(dy), round(dx)) for dy, dx, _ in found] == [(-12, 10), (10, -14)]
    assert found[0][2] == pytest.approx(0.6, abs=0.01)
    assert len(secondary_peaks(response, (6.0, 6.0), 0.3, max_peaks=1)) == 1
    assert secondary_peaks(-response, (6.0, 6.0), 0.3, 5) == []  # no positive main peak: nothing to compare with


def test_bank_margin_is_nearest_positive_minus_nearest_negative_and_infinite_without_negatives():
    e = np.eye(3)
    bank = LookalikeBank(size=2)
    bank.add_positive(e[0])
    assert bank.margin(e[0]) == math.inf  # no look-alikes seen: nothing to tell apart
    bank.add_negative(e[1])
    assert bank.margin(e[0]) == pytest.approx(1.0) and bank.margin(e[1]) == pytest.approx(-1.0)
    mixed = (e[0] + e[1]) / math.sqrt(2)
    assert bank.margin(mixed) == pytest.approx(0.0)
    for _ in range(3):
        bank.add_positive(e[2])  # the bank keeps `size` recent positives and the first for good
    assert len(bank.positives) == 2 and bank.similarities(e[0])[0] == pytest.approx(1.0)
    assert nearest_similarity(e[0], []) == -math.inf


@pytest.mark.parametrize("mapping, key", [
    ({"lookalike": {"min_margin": 3.0}}, "redetect.lookalike.min_margin"),
    ({"lookalike": {"peak_fraction": 0.0}}, "redetect.lookalike.peak_fraction"),
    ({"lookalike": {"bank_size": 0}}, "redetect.lookalike.bank_size"),
    ({"lookalike": {"learn_every": 0}}, "redetect.lookalike.learn_every"),
])
def test_lookalike_parameters_are_validated_with_the_key_named(mapping, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        RedetectParams.from_mapping(mapping)
