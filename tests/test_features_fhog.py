"""fHOG properties: shape, orientation bins, clipping, contrast invariance, zeros, batch consistency."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from jsar.features import fhog as fh


def ramp(angle_deg: float, size: int = 32, slope: float = 3.0) -> np.ndarray:
    """Float image whose gradient points at angle_deg (image coordinates: x right, y down)."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    theta = np.deg2rad(angle_deg)
    return (128.0 + slope * (x * np.cos(theta) + y * np.sin(theta))).astype(np.float32)


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    rng = np.random.default_rng(7)
    return cv2.GaussianBlur(rng.uniform(0, 100, (64, 48)).astype(np.float32), (0, 0), 1.5)


def test_shape_and_dtype(texture):
    out = fh.fhog(texture, cell=4)
    assert out.shape == (16, 12, 31) and out.dtype == np.float32
    assert fh.fhog(np.zeros((18, 23, 3), np.uint8), cell=4).shape == (4, 5, 31)


@pytest.mark.parametrize("k", [0, 2, 5, 9, 13, 17])
def test_gradient_direction_lands_in_its_signed_and_unsigned_bins(k):
    out = fh.fhog(ramp(20.0 * k))
    inner = out[1:-1, 1:-1]  # away from the one-sided border gradients
    assert np.all(np.argmax(inner[..., :18], axis=-1) == k)
    assert np.all(np.argmax(inner[..., 18:27], axis=-1) == k % 9)


def test_between_two_bins_the_magnitude_is_split_evenly():
    hist = fh.orientation_histograms(*fh.gradients(ramp(30.0)[None]), cell=4)[0, 2, 2]
    assert hist[1] == pytest.approx(hist[2], rel=1e-3) and hist[1] > 0
    assert np.sum(hist) == pytest.approx(hist[1] + hist[2], rel=1e-5)


def test_normalised_values_are_clipped_at_0_2(texture):
    # What is tested: every block-normalised histogram value min(h * n_k, 0.2), before the four
    # blocks are summed, is <= 0.2, and the clip is active (a single-orientation cell reaches it).
    for image in (texture, ramp(40.0)):
        hist = fh.orientation_histograms(*fh.gradients(image[None]), cell=4)
        clipped = fh.clipped_normalised(hist)
        assert clipped.max() <= fh.CLIP
    assert np.isclose(fh.clipped_normalised(fh.orientation_histograms(*fh.gradients(ramp(40.0)[None]), 4)).max(), 0.2)
    out = fh.fhog(texture)
    assert out[..., :27].max() <= 0.5 * 4 * 0.2 + 1e-6  # four clipped blocks, halved
    assert out[..., 27:].max() <= fh.TEXTURE_SCALE * 18 * 0.2 + 1e-6  # 18 clipped values of one block
    # Compiled path, exactly: on a 40 degree ramp an inner cell holds one bin h, each block's energy
    # is 4 h^2, so h * n_k = 0.5 is clipped to 0.2 in all four blocks.
    inner = fh.fhog(ramp(40.0))[2:-2, 2:-2]
    assert np.allclose(inner[..., 2], 0.5 * 4 * 0.2, atol=1e-5)  # signed bin 2
    assert np.allclose(inner[..., 18 + 2], 0.5 * 4 * 0.2, atol=1e-5)  # unsigned bin 2
    assert np.allclose(inner[..., 27:], fh.TEXTURE_SCALE * 0.2, atol=1e-5)  # one clipped value per block


def test_contrast_invariance(texture):
    base = fh.fhog(texture)
    for k in (0.5, 2.5):
        assert np.abs(fh.fhog(texture * k) - base).max() < 1e-3  # equal up to eps / energy


def test_zero_and_constant_images_give_zero_features():
    assert not np.any(fh.fhog(np.zeros((20, 20), np.uint8)))
    assert not np.any(fh.fhog(np.full((20, 20, 3), 77, np.uint8)))


def test_colour_uses_the_channel_with_the_strongest_gradient(texture):
    colour = np.zeros(texture.shape + (3,), np.float32)
    colour[..., 1] = texture
    colour[..., 2] = texture * 0.3  # weaker copy: never the strongest
    assert np.allclose(fh.fhog(colour), fh.fhog(texture), atol=1e-6)


def test_batch_equals_per_image(texture):
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, (5, 16, 32), dtype=np.uint8)
    batch = fh.fhog_batch(images)
    assert batch.shape == (5, 4, 8, 31)
    for n in range(5):
        assert np.allclose(batch[n], fh.fhog(images[n]), atol=1e-6)


@pytest.mark.parametrize("shape", [(3, 16, 32), (2, 23, 18, 3), (1, 9, 41)])
def test_compiled_kernel_matches_numpy_reference(shape):
    rng = np.random.default_rng(sum(shape))
    images = rng.integers(0, 256, shape, dtype=np.uint8)
    assert np.allclose(fh.fhog_batch(images), fh.fhog_batch_reference(images), atol=2e-5)
    smooth = images.astype(np.float32) * 0.37
    assert np.allclose(fh.fhog_batch(smooth), fh.fhog_batch_reference(smooth), atol=2e-5)


@pytest.mark.parametrize(
    "image, cell",
    [(np.zeros((3, 8)), 4), (np.full((8, 8), np.nan), 4), (np.zeros((8, 8, 2)), 4), (np.zeros((8, 8)), 0), ([[1, 2]], 1), (np.zeros((8, 8), complex), 4)],
)
def test_bad_input_raises_value_error(image, cell):
    with pytest.raises(ValueError):
        fh.fhog(image, cell)


def bits(values: np.ndarray) -> np.ndarray:
    """The float32 array's bit patterns: equal bits, equal numbers (signed zeros included)."""
    return np.ascontiguousarray(values, dtype=np.float32).view(np.uint32)


def assert_same_bits_as_reference_loops(images: np.ndarray, cell: int) -> None:
    assert np.array_equal(bits(fh.fhog_batch(images, cell)), bits(fh.fhog_batch_reference_loops(images, cell)))


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("shape", [(3, 40, 12), (2, 37, 23), (2, 23, 18, 3), (4, 5, 5), (3, 1, 9), (3, 9, 1), (2, 4, 4, 3),
                                   (1, 300, 8), (1, 33, 64, 3), (2, 7, 6)])
@pytest.mark.parametrize("cell", [4, 1, 3])
def test_kernel_gives_the_reference_loops_numbers_to_the_bit_on_random_images(shape, dtype, cell):
    if shape[1] < cell or shape[2] < cell:
        pytest.skip("smaller than a cell")
    rng = np.random.default_rng(sum(shape) + cell)
    images = rng.integers(0, 256, shape).astype(dtype)
    assert_same_bits_as_reference_loops(images, cell)
    if dtype == np.float32:
        assert_same_bits_as_reference_loops(rng.uniform(0, 255, shape).astype(np.float32), cell)
    flat = np.zeros(shape, dtype)
    flat[..., : shape[2] // 2] = 9  # flat regions (zero gradients) next to one edge
    assert_same_bits_as_reference_loops(flat, cell)


def test_kernel_gives_the_reference_loops_numbers_to_the_bit_on_real_frames(data_root):
    rng = np.random.default_rng(44)
    frames = sorted(data_root.glob("*/img/*.jpg"))[::61]
    assert frames
    for path in frames:
        frame = cv2.imread(str(path))
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        # The size filter's grid (169 grey patches of one model size) and the translation patch (200 x 200 BGR).
        size_batch = np.stack([cv2.resize(grey[y:y + 60, x:x + 20], (12, 40), interpolation=cv2.INTER_AREA)
                               for y, x in rng.integers(0, 100, (169, 2))])
        assert_same_bits_as_reference_loops(size_batch, 4)
        y, x = rng.integers(0, 30, 2)
        assert_same_bits_as_reference_loops(np.ascontiguousarray(frame[None, y:y + 200, x:x + 200]), 4)
        assert_same_bits_as_reference_loops(np.ascontiguousarray(frame[None, y:y + 97, x:x + 131]), 4)
        assert_same_bits_as_reference_loops(grey[None, y:y + 61, x:x + 203].astype(np.float32), 4)


def test_batch_writes_into_a_feature_stack():
    rng = np.random.default_rng(5)
    images = rng.integers(0, 256, (2, 16, 24), dtype=np.uint8)
    stack = np.full((2, 4, 6, 40), 7.0, np.float32)
    view = fh.fhog_batch(images, 4, stack=stack, channel=3)
    assert np.array_equal(view, fh.fhog_batch(images, 4)) and np.shares_memory(view, stack)
    assert np.all(stack[..., :3] == 7.0) and np.all(stack[..., 34:] == 7.0)  # the other channels are untouched
    for wrong, channel in [(np.zeros((2, 4, 6, 40)), 0), (np.zeros((2, 4, 6, 30), np.float32), 0),
                           (np.zeros((2, 4, 6, 40), np.float32), 10), (np.zeros((2, 4, 6, 80), np.float32)[..., ::2], 0)]:
        with pytest.raises(ValueError):
            fh.fhog_batch(images, 4, stack=wrong, channel=channel)
