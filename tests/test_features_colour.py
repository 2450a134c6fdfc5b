"""Colour attributes (derived table, projection, loader) and the translation feature stack."""
from __future__ import annotations

import numpy as np
import pytest

from jsar.features import colour as col
from jsar.features.fhog import fhog
from jsar.features.translation import colour_cells_reference, extract_features


@pytest.fixture(scope="module")
def probabilities() -> np.ndarray:
    return col.colour_term_probabilities()


@pytest.fixture(scope="module")
def table(probabilities) -> np.ndarray:
    return col.project_terms(probabilities)


def row_of(r: int, g: int, b: int) -> int:
    return r // 8 + 32 * (g // 8) + 1024 * (b // 8)


def test_table_shape_and_probabilities(probabilities, table):
    assert probabilities.shape == (32768, 11) and table.shape == (32768, 10) and table.dtype == np.float32
    assert np.allclose(probabilities.sum(axis=1), 1.0, atol=1e-5)
    assert np.all(probabilities >= 0)


@pytest.mark.parametrize(
    "rgb, term",
    [((255, 0, 0), "red"), ((0, 200, 0), "green"), ((0, 0, 255), "blue"), ((255, 255, 0), "yellow"),
     ((255, 255, 255), "white"), ((0, 0, 0), "black"), ((128, 128, 128), "grey"), ((255, 128, 0), "orange"),
     ((128, 0, 128), "purple"), ((255, 170, 200), "pink"), ((140, 80, 40), "brown")],
)
def test_pure_colours_map_to_their_term(probabilities, rgb, term):
    assert col.COLOUR_TERMS[int(np.argmax(probabilities[row_of(*rgb)]))] == term


def test_projection_is_an_isometry_of_the_simplex(probabilities, table):
    basis = col.simplex_basis()
    assert np.allclose(basis.T @ basis, np.eye(10)) and np.allclose(basis.sum(axis=0), 0.0)
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, 32768, 50), rng.integers(0, 32768, 50)
    dist11 = np.linalg.norm(probabilities[i] - probabilities[j], axis=1)
    dist10 = np.linalg.norm(table[i] - table[j], axis=1)
    assert np.allclose(dist10, dist11, atol=1e-5)
    # Nothing is lost: the 11 probabilities come back from the 10 channels.
    assert np.allclose(table @ basis.T + 1.0 / 11.0, probabilities, atol=1e-5)


def test_load_external_tables(tmp_path, probabilities, table):
    path11 = tmp_path / "t11.npy"
    np.save(path11, probabilities.astype(np.float64))
    assert np.allclose(col.load_colour_table(path11), table, atol=1e-6)
    path10 = tmp_path / "t10.npy"
    np.save(path10, table)
    assert np.array_equal(col.load_colour_table(path10), table)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((32768, 9), np.float32), np.zeros((1000, 10), np.float32), np.zeros((32768, 10), np.int32),
     np.full((32768, 10), np.nan, np.float32)],
)
def test_bad_external_table_raises_value_error(tmp_path, bad):
    path = tmp_path / "bad.npy"
    np.save(path, bad)
    with pytest.raises(ValueError):
        col.load_colour_table(path)
    with pytest.raises(ValueError):
        col.load_colour_table(tmp_path / "missing.npy")


def test_bgr_pixels_are_indexed_as_rgb(table):
    bgr = np.array([[[0, 0, 255]]], np.uint8)  # red in OpenCV's BGR order
    assert col.colour_index(bgr)[0, 0] == row_of(255, 0, 0)
    assert np.array_equal(col.colour_attributes(bgr, table)[0, 0], table[row_of(255, 0, 0)])


def test_extract_features_channels(table):
    rng = np.random.default_rng(5)
    patch = rng.integers(0, 256, (40, 48, 3), dtype=np.uint8)
    feat = extract_features(patch, 4, table)
    assert feat.shape == (10, 12, 42) and feat.dtype == np.float32
    assert np.allclose(feat[..., 1:32], fhog(patch, 4))
    grey = extract_features(patch[..., 0], 4, None)
    assert grey.shape == (10, 12, 32)
    assert extract_features(patch, 4, None).shape == (10, 12, 32)


def test_compiled_colour_cells_match_numpy_reference(table):
    rng = np.random.default_rng(9)
    patch = rng.integers(0, 256, (22, 37, 3), dtype=np.uint8)
    feat = extract_features(patch, 4, table)
    assert np.allclose(feat[..., 32:], colour_cells_reference(patch, 4, table), atol=1e-6)


def test_extract_features_cell_averages():
    patch = np.zeros((8, 8, 3), np.uint8)
    patch[:4, :4] = (0, 0, 255)  # a red cell
    patch[4:, 4:] = 255  # a white cell
    table = col.derived_colour_table()
    feat = extract_features(patch, 4, table)
    assert feat[0, 0, 0] == pytest.approx(np.round(0.299 * 255) / 255 - 0.5, abs=1e-6)
    assert feat[1, 1, 0] == pytest.approx(0.5)
    assert np.allclose(feat[0, 0, 32:], table[row_of(255, 0, 0)], atol=1e-6)
    assert np.allclose(feat[1, 1, 32:], table[row_of(255, 255, 255)], atol=1e-6)


@pytest.mark.parametrize(
    "patch, table",
    [(np.zeros((8, 8), np.uint8), "table"), (np.zeros((8, 8, 3), np.float32), None), (np.zeros((2, 8, 3), np.uint8), None),
     (np.zeros((8, 8, 3), np.uint8), np.zeros((32768, 11), np.float32))],
)
def test_extract_features_bad_input(patch, table):
    table_value = col.derived_colour_table() if isinstance(table, str) else table
    with pytest.raises(ValueError):
        extract_features(patch, 4, table_value)


def test_colour_cells_give_the_reference_loops_numbers_to_the_bit(table, data_root):
    import cv2

    from jsar.features._native import kernels
    from jsar.features.translation import colour_cells_reference_loops

    rng = np.random.default_rng(44)
    tables = [table, rng.uniform(0, 1, (32768, 10)).astype(np.float32)]
    patches = [rng.integers(0, 256, shape, dtype=np.uint8) for shape in [(40, 12, 3), (13, 17, 3), (1, 9, 3), (5, 5, 3)]]
    for path in sorted(data_root.glob("*/img/*.jpg"))[::61]:
        frame = cv2.imread(str(path))
        y, x = rng.integers(0, 30, 2)
        patches += [np.ascontiguousarray(frame[y:y + 200, x:x + 200]), np.ascontiguousarray(frame[y:y + 97, x:x + 131])]
    for patch in patches:
        for colour_table in tables:
            for cell in (4, 1, 3):
                if min(patch.shape[:2]) < cell:
                    continue
                fast = extract_features(patch, cell, colour_table)[..., 32:]
                assert np.array_equal(fast.view(np.uint32),
                                      colour_cells_reference_loops(patch, cell, colour_table).view(np.uint32))
        # Tables of other widths take the kernel's general path.
        narrow = rng.uniform(0, 1, (32768, 7)).astype(np.float32)
        hc, wc = patch.shape[0] // 4, patch.shape[1] // 4
        if hc and wc:
            outs = [np.empty((hc, wc, 7), np.float32) for _ in range(2)]
            kernels.colour_cells(patch, patch.shape[0], patch.shape[1], narrow, 7, 4, outs[0])
            kernels.colour_cells_reference(patch, patch.shape[0], patch.shape[1], narrow, 7, 4, outs[1])
            assert np.array_equal(outs[0].view(np.uint32), outs[1].view(np.uint32))


def test_feature_stack_holds_the_reference_loops_numbers_to_the_bit(table, data_root):
    """extract_features' kernels write into the stack: channels 1..31 are fHOG's, 32..41 the colour cells', bit for bit."""
    import cv2

    from jsar.features.fhog import fhog_batch_reference_loops
    from jsar.features.translation import colour_cells_reference_loops

    rng = np.random.default_rng(45)
    patches = [rng.integers(0, 256, shape, dtype=np.uint8) for shape in [(40, 12, 3), (13, 17, 3), (5, 4, 3), (23, 9)]]
    for path in sorted(data_root.glob("*/img/*.jpg"))[::61]:
        frame = cv2.imread(str(path))
        patches += [np.ascontiguousarray(frame[:200, :200]), np.ascontiguousarray(frame[7:104, 3:134])]
    for patch in patches:
        for cell in (4, 3):
            colour_table = table if patch.ndim == 3 else None
            stack = extract_features(patch, cell, colour_table)
            assert np.array_equal(stack[..., 1:32].view(np.uint32),
                                  fhog_batch_reference_loops(patch[None], cell)[0].view(np.uint32))
            if colour_table is not None:
                assert np.array_equal(stack[..., 32:].view(np.uint32),
                                      colour_cells_reference_loops(patch, cell, colour_table).view(np.uint32))
