"""Patch sampling: agreement with OpenCV's resize on whole-pixel regions, border replication, bounds."""
from __future__ import annotations

import tracemalloc

import cv2
import numpy as np
import pytest

from jsar.features.patches import resample_regions, resample_regions_reference, sample_patch, sample_patches


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    rng = np.random.default_rng(1)
    noise = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    return cv2.GaussianBlur(noise, (0, 0), 2.0)


@pytest.mark.parametrize("x, y, w, h, out_w, out_h", [(40, 30, 150, 120, 50, 40), (10, 20, 97, 53, 32, 16)])
def test_shrinking_whole_pixel_region_equals_cv2_inter_area(frame, x, y, w, h, out_w, out_h):
    patch = sample_patch(frame, (x + w / 2, y + h / 2), (w, h), (out_w, out_h))
    expected = cv2.resize(frame[y:y + h, x:x + w], (out_w, out_h), interpolation=cv2.INTER_AREA)
    assert patch.dtype == np.uint8 and patch.shape == (out_h, out_w, 3)
    assert np.abs(patch.astype(int) - expected).max() <= 1


def test_enlarging_matches_cv2_inter_linear(frame):
    x, y, w, h = 50, 60, 40, 30
    patch = sample_patch(frame, (x + w / 2, y + h / 2), (w, h), (200, 150))
    expected = cv2.resize(frame[y:y + h, x:x + w], (200, 150), interpolation=cv2.INTER_LINEAR)
    # OpenCV quantises interpolation weights to 1/32 (fixed point); this module does not.
    # Outer samples differ: cv2.resize replicates the crop's edge, this reads the image around it.
    assert np.abs(patch.astype(int) - expected)[5:-5, 5:-5].max() <= 3


def test_region_across_the_border_replicates_border_pixels(frame):
    x, y, w, h = -30, -20, 100, 80  # sticks out left and top
    pad = cv2.copyMakeBorder(frame, 20, 0, 30, 0, cv2.BORDER_REPLICATE)
    expected = cv2.resize(pad[0:h, 0:w], (50, 40), interpolation=cv2.INTER_AREA)
    patch = sample_patch(frame, (x + w / 2, y + h / 2), (w, h), (50, 40))
    assert np.abs(patch.astype(int) - expected).max() <= 1


def test_region_far_outside_is_the_replicated_edge_without_a_huge_copy(frame):
    tracemalloc.start()
    patch = sample_patch(frame, (-1e6, 100.0), (5e4, 100.0), (20, 20))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    # Far left: every column is the image's column 0 (rows 50..149) averaged down to 20 rows.
    column = cv2.resize(frame[50:150, :1], (1, 20), interpolation=cv2.INTER_AREA)
    assert np.abs(patch.astype(int) - column).max() <= 1
    assert peak < 1_000_000  # numpy-side allocations; a padded copy of the region would need 15 MB


def test_huge_region_is_not_copied(frame):
    tracemalloc.start()
    patch = sample_patch(frame, (160.0, 120.0), (1e5, 1e5), (10, 10))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 1_000_000  # numpy-side allocations; a padded copy would need 30 GB
    # The image is a tiny part of the region: the centre sample is an average of the whole image.
    assert np.abs(patch[5, 5].astype(float) - frame.reshape(-1, 3).mean(axis=0)).max() < 60


def test_sub_pixel_region_is_bilinear_value_at_its_centre():
    image = np.array([[0, 100], [100, 200]], np.uint8)
    assert sample_patch(image, (1.0, 1.0), (0.1, 0.1), (1, 1))[0, 0] == 100  # between the four pixels
    assert sample_patch(image, (1.25, 1.0), (0.1, 0.1), (1, 1))[0, 0] == 125
    patch = sample_patch(image, (1.0, 1.0), (0.1, 0.1), (3, 3))
    assert patch[1, 1] == 100 and patch[0, 0] < 100 < patch[2, 2]


def test_grey_frame_and_4k_frame():
    frame4k = np.zeros((2160, 3840), np.uint8)
    frame4k[:, 1920:] = 200
    patch = sample_patch(frame4k, (1920.0, 1080.0), (1000.0, 1000.0), (200, 200))
    assert patch.shape == (200, 200)
    assert np.all(patch[:, :100] == 0) and np.all(patch[:, 100:] == 200)


def test_fractional_shift_moves_the_content():
    ramp = np.tile(np.arange(0, 200, 2, dtype=np.uint8), (10, 1))  # value = 2 * x_index
    for size, out in ((20.0, 40), (39.0, 13)):  # enlarging; shrinking by a whole factor
        left = resample_regions(ramp, (50.5, 5.0), [[size, 4.0]], (out, 8))
        right = resample_regions(ramp, (51.0, 5.0), [[size, 4.0]], (out, 8))
        assert np.allclose(right - left, 1.0, atol=1e-3)  # half a pixel on a slope of 2 per pixel


def test_batch_equals_single_patches(frame):
    sizes = np.array([[40.0, 20.0], [57.3, 31.1], [13.2, 8.7], [300.0, 9.0]])
    batch = sample_patches(frame, (100.3, 80.6), sizes, (32, 16))
    assert batch.shape == (4, 16, 32, 3)
    for n, size in enumerate(sizes):
        assert np.array_equal(batch[n], sample_patch(frame, (100.3, 80.6), size, (32, 16)))


@pytest.mark.parametrize("channels", [1, 3])
def test_compiled_kernel_matches_numpy_reference(frame, channels):
    image = frame if channels == 3 else frame[..., 1].copy()
    rng = np.random.default_rng(11)
    for centre in [(160.3, 120.8), (-5.5, 7.25), (330.0, 250.0), (2.0, 118.0)]:
        sizes = rng.uniform(0.3, 150.0, (25, 2))  # enlarging, shrinking and mixed axes
        out = resample_regions(image, centre, sizes, (32, 16))
        ref = resample_regions_reference(image, centre, sizes, (32, 16))
        assert np.allclose(out, ref, atol=2e-3)


@pytest.mark.parametrize(
    "args",
    [
        (np.zeros((0, 5), np.uint8), (1, 1), (2, 2), (4, 4)),
        (np.zeros((5, 5, 2), np.uint8), (1, 1), (2, 2), (4, 4)),
        (np.zeros((5, 5), np.uint8), (1, np.nan), (2, 2), (4, 4)),
        (np.zeros((5, 5), np.uint8), (1, 1), (0, 2), (4, 4)),
        (np.zeros((5, 5), np.uint8), (1, 1), (2, 2), (0, 4)),
    ],
)
def test_bad_input_raises_value_error(args):
    with pytest.raises(ValueError):
        sample_patch(*args)


def test_compiled_kernels_reject_undersized_buffers_instead_of_reading_past_them():
    from jsar.features._native import kernels

    image = np.zeros((10, 10), np.uint8)
    sizes = np.array([[4.0, 4.0]])
    with pytest.raises(ValueError):  # image buffer smaller than the H x W x C it is said to be
        kernels.resample(image, 20, 10, 1, 5.0, 5.0, sizes, 1, 4, 4, np.empty((1, 4, 4), np.uint8), True)
    with pytest.raises(ValueError):  # output too small
        kernels.resample(image, 10, 10, 1, 5.0, 5.0, sizes, 1, 4, 4, np.empty((1, 4, 3), np.uint8), True)
    with pytest.raises(ValueError):
        kernels.fhog(image, 1, 10, 10, 1, True, 4, np.empty((1, 2, 2, 30), np.float32))
    with pytest.raises(ValueError):
        kernels.colour_cells(image, 10, 10, np.zeros((32768, 10), np.float32), 10, 4,
                             np.empty((2, 2, 10), np.float32))  # a grey image is not H x W x 3


def test_kernel_gives_the_reference_loops_numbers_to_the_bit(data_root):
    from jsar.features.patches import resample_reference_loops

    rng = np.random.default_rng(44)
    images = []
    for path in sorted(data_root.glob("*/img/*.jpg"))[::61]:
        bgr = cv2.imread(str(path))
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        # Whole frames, and crops small enough for the kernel's float copy of the image (the size filter's grey region).
        images += [bgr, grey, np.ascontiguousarray(grey[40:112, 30:61]), np.ascontiguousarray(bgr[10:90, 20:150])]
    images += [rng.integers(0, 256, (1, 7, 3), dtype=np.uint8), rng.integers(0, 256, (37, 53), dtype=np.uint8)]
    for image in images:
        height, width = image.shape[:2]
        for _ in range(3):
            centre = rng.uniform(-40, max(height, width) + 40, 2)
            sizes = rng.uniform(0.5, 250, 2) * rng.uniform(0.7, 1.4, (int(rng.integers(1, 8)), 2))
            for out_wh in [(12, 40), (200, 200), (7, 3), (1, 1)]:
                assert np.array_equal(sample_patches(image, centre, sizes, out_wh),
                                      resample_reference_loops(image, centre, sizes, out_wh))
                assert np.array_equal(resample_regions(image, centre, sizes, out_wh).view(np.uint32),
                                      resample_reference_loops(image, centre, sizes, out_wh, np.float32).view(np.uint32))


@pytest.mark.parametrize("channels", [1, 3])
def test_kernel_gives_the_reference_loops_numbers_to_the_bit_for_every_tap_count(channels):
    """Regions shrunk 0.7-4.5x onto 200 x 200 and 28 x 20 (two to six taps an output pixel, the counts the kernel's
    loops are specialised for among them), from an image too large for its float copy and from one small enough."""
    from jsar.features.patches import resample_reference_loops

    rng = np.random.default_rng(channels)
    texture = np.cumsum(rng.integers(0, 256, (720, 1280, channels)), axis=1) // 30 % 256
    large = np.ascontiguousarray(texture.astype(np.uint8).squeeze())
    small = np.ascontiguousarray(large[100:190, 200:330])
    for image, out_wh, sides in ((large, (200, 200), (140, 900)), (small, (28, 20), (20, 90))):
        for _ in range(40):
            centre = rng.uniform(0, min(image.shape[:2]), 2)
            side = rng.uniform(*sides)
            sizes = np.array([[side, side * rng.uniform(0.7, 1.3)]])
            assert np.array_equal(sample_patches(image, centre, sizes, out_wh),
                                  resample_reference_loops(image, centre, sizes, out_wh)), (side, out_wh)
