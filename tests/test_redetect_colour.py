"""The colour check on re-detection candidates (jsar/redetect/colour_check.py): pure parts."""
from __future__ import annotations

import math

import numpy as np
import pytest

from jsar.redetect.colour_check import ColourModel, bhattacharyya, histogram, region_pixels, target_colours
from jsar.redetect.params import RedetectParams

RED, BLUE, GREY, BROWN = (0, 0, 220), (220, 0, 0), (128, 128, 128), (30, 60, 100)  # BGR


def _scene() -> np.ndarray:
    """A 100 x 200 grey frame; 20 x 20 boxes at y 40: at x 20 red over grey (the target), at x 120 blue
    over grey (other colours, same layout), at x 160 red over brown (the target on other ground)."""
    frame = np.full((100, 200, 3), GREY, np.uint8)
    frame[40:50, 20:40] = RED
    frame[40:50, 120:140] = BLUE
    frame[40:50, 160:180] = RED
    frame[50:60, 160:180] = BROWN
    return frame


TARGET = (20.0, 40.0, 20.0, 20.0)


def test_region_pixels_rounds_clips_and_marks_the_box_inside_its_surround():
    frame = np.arange(10 * 12 * 3, dtype=np.uint8).reshape(10, 12, 3)
    pixels, inside = region_pixels(frame, (4.2, 3.6, 4.0, 4.0))  # x 4..8, y 4..8
    assert pixels.shape == (16, 3) and inside.all()
    pixels, inside = region_pixels(frame, (4.0, 4.0, 4.0, 4.0), scale=2.0)  # x 2..10, y 2..10
    assert pixels.shape == (64, 3) and inside.sum() == 16
    assert np.array_equal(pixels[inside], frame[4:8, 4:8].reshape(-1, 3))
    pixels, inside = region_pixels(frame, (-3.0, -3.0, 5.0, 5.0))  # clipped to x 0..2, y 0..2
    assert pixels.shape == (4, 3)
    assert region_pixels(frame, (20.0, 20.0, 3.0, 3.0))[0].shape == (0, 3)
    assert region_pixels(frame[:, :, 0], (0.0, 0.0, 2.0, 3.0))[0].shape == (6,)
    # A large region is sampled on a grid: every 2nd row and column of 10 x 12 for at most 30 pixels.
    pixels, inside = region_pixels(frame, (0.0, 0.0, 12.0, 10.0), max_pixels=30)
    assert np.array_equal(pixels, frame[::2, ::2].reshape(-1, 3))


def test_histogram_is_normalised_and_puts_each_channel_level_in_its_bin():
    pixels = np.array([[0, 0, 0], [255, 255, 255], [255, 255, 255], [32, 0, 255]], np.uint8)
    counts = histogram(pixels, 8)
    assert counts.shape == (512,) and counts.sum() == pytest.approx(1.0)
    assert counts[0] == pytest.approx(0.25) and counts[511] == pytest.approx(0.5)
    assert counts[(1 * 8 + 0) * 8 + 7] == pytest.approx(0.25)  # levels (1, 0, 7)
    assert histogram(np.array([0, 255], np.uint8), 4).tolist() == [0.5, 0.0, 0.0, 0.5]
    assert histogram(np.empty((0, 3), np.uint8), 8) is None


def test_a_colour_is_the_targets_where_it_is_likelier_in_the_box_than_in_the_surround():
    object_hist = np.array([0.5, 0.5, 0.0, 0.0])
    surround_hist = np.array([0.0, 0.2, 0.8, 0.0])
    # Surround three times the box's area: colour 1 is 0.5 in the box against 3 x 0.2 around it.
    assert target_colours(object_hist, surround_hist, 3.0).tolist() == [True, False, False, False]
    assert target_colours(object_hist, surround_hist, 2.0).tolist() == [True, True, False, False]


def test_bhattacharyya_is_one_for_the_same_histogram_and_zero_for_disjoint_ones():
    p = np.array([0.5, 0.5, 0.0, 0.0])
    assert bhattacharyya(p, p) == pytest.approx(1.0)
    assert bhattacharyya(p, np.array([0.0, 0.0, 0.3, 0.7])) == 0.0
    assert bhattacharyya(p, np.array([0.5, 0.0, 0.5, 0.0])) == pytest.approx(0.5)


def test_the_model_matches_a_box_by_the_better_of_similarity_and_share_of_the_targets_colours():
    frame = _scene()
    model = ColourModel(bins=8, rate=0.05, reference_rate=0.1, surround_scale=2.0)
    assert model.relative_match(frame, TARGET) == math.inf  # nothing learnt yet
    model.learn(frame, TARGET)
    # Red is the target's colour, grey is everywhere around it: half the box is in the target's colours.
    assert model.share_reference == pytest.approx(0.5) and model.similarity_reference == pytest.approx(1.0)
    assert model.relative_match(frame, TARGET) == pytest.approx(1.0)
    # The target on other ground: its histogram's similarity halves (0.5), its own colours are all there.
    assert model.relative_match(frame, (160.0, 40.0, 20.0, 20.0)) == pytest.approx(1.0)
    # Same layout, other colours: none of the target's colours; only the grey half is similar.
    assert model.relative_match(frame, (120.0, 40.0, 20.0, 20.0)) == pytest.approx(0.5)
    # Background: grey, like half the target's box; a quarter red (half off the target) is closer.
    assert model.relative_match(frame, (60.0, 10.0, 20.0, 20.0)) == pytest.approx(math.sqrt(0.5))
    assert model.relative_match(frame, (30.0, 40.0, 20.0, 20.0)) == pytest.approx(
        math.sqrt(0.5 * 0.25) + math.sqrt(0.5 * 0.75))
    assert model.relative_match(frame, (300.0, 40.0, 20.0, 20.0)) == 0.0  # outside the frame


def test_the_model_blends_a_new_look_in_at_its_rate():
    frame = _scene()
    model = ColourModel(bins=8, rate=0.25, reference_rate=0.5, surround_scale=2.0)
    model.learn(frame, TARGET)
    red_object, red_surround = model.object_hist.copy(), model.surround_hist.copy()
    blue_box = (120.0, 40.0, 20.0, 20.0)
    model.learn(frame, blue_box)  # the target now looks blue
    pixels, inside = region_pixels(frame, blue_box, 2.0)
    blue_object = histogram(pixels[inside], 8)
    assert np.allclose(model.object_hist, 0.75 * red_object + 0.25 * blue_object)
    assert np.allclose(model.surround_hist, 0.75 * red_surround + 0.25 * histogram(pixels[~inside], 8))
    # Red and blue are both the target's now: half of the blue box is in its colours.
    assert model.share_reference == pytest.approx(0.5)
    assert model.similarity_reference == pytest.approx(0.5 + 0.5 * bhattacharyya(model.object_hist, blue_object))
    model.learn(frame, (500.0, 40.0, 20.0, 20.0))  # outside the frame: nothing learnt
    assert np.allclose(model.object_hist, 0.75 * red_object + 0.25 * blue_object)


@pytest.mark.parametrize("key, value", [("min_match", 1.5), ("core_min_match", -0.1), ("bins", 1), ("surround_scale", 1.0),
                                        ("rate", 0.0), ("reference_rate", 2.0)])
def test_colour_parameters_are_validated_with_the_key_named(key, value):
    with pytest.raises(ValueError, match=f"redetect.colour.{key}"):
        RedetectParams.from_mapping({"colour": {key: value}})
