"""The colour check on re-detection candidates (jsar/redetect/colour_check.py): pure parts."""
from __future__ import annotations

import math

import numpy as np
import pytest

import jsar

from jsar.redetect.colour_check import (DARK_BIN, GREYS, HUES, SATURATIONS, AnchorColours, ColourModel, bhattacharyya, histogram,
                                      hue_histogram, inner_box, region_pixels, target_colours)
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


@pytest.mark.parametrize("bins", [2, 5, 8, 32])
def test_histograms_count_each_pixel_at_its_levels_bin_and_split_by_the_mask(bins):
    """colour_index against the levels' definition ((v * bins) >> 8 per channel, channel 0 most significant), and
    split_histograms against two histograms of the masked pixels, to the bit, grey pixels and an empty side too."""
    from jsar.redetect.colour_check import colour_index, split_histograms
    rng = np.random.default_rng(bins)
    for pixels in (rng.integers(0, 256, (500, 3), dtype=np.uint8), rng.integers(0, 256, 300, dtype=np.uint8)):
        levels = (pixels.astype(np.int64) * bins) >> 8
        expected = (levels if pixels.ndim == 1
                    else np.ravel_multi_index(tuple(levels.T), (bins,) * pixels.shape[1]))
        np.testing.assert_array_equal(colour_index(pixels, bins), expected)
        for inside in (rng.random(len(pixels)) < 0.3, np.ones(len(pixels), bool)):
            obj, sur = split_histograms(pixels, inside, bins)
            np.testing.assert_array_equal(obj, histogram(pixels[inside], bins))
            if inside.all():
                assert sur is None and histogram(pixels[~inside], bins) is None
            else:
                np.testing.assert_array_equal(sur, histogram(pixels[~inside], bins))


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


# ---------------------------------------------------------------- the drift check's colours (AnchorColours)

def _loose_box_scene() -> np.ndarray:
    """A 120 x 160 green frame with a 20 x 20 red target at (70, 50) on a 40 x 40 grey patch at (60, 40)
    (the road under it); a green patch at (10, 10) and a red one at (120, 80)."""
    green, road = (40, 160, 40), (128, 128, 128)
    frame = np.full((120, 160, 3), green, np.uint8)
    frame[40:80, 60:100] = road
    frame[50:70, 70:90] = RED
    frame[80:100, 120:140] = RED
    return frame


LOOSE = (60.0, 40.0, 40.0, 40.0)  # a loose box: the target in its centre, road in its corners


def _anchor(frame: np.ndarray, box=LOOSE, min_reference: float = 0.3) -> AnchorColours:
    return AnchorColours(frame, box, surround_scale=2.0, inner=0.6, min_reference=min_reference)


def test_inner_box_keeps_the_centre_and_scales_the_sides():
    assert inner_box((10.0, 20.0, 40.0, 20.0), 0.5) == (20.0, 25.0, 20.0, 10.0)


def test_the_anchor_takes_the_centres_colours_not_a_loose_boxs_corners():
    frame = _loose_box_scene()
    anchor = _anchor(frame)
    assert anchor.usable
    assert anchor.share(frame, LOOSE) == pytest.approx(1.0)
    assert anchor.share(frame, (120.0, 80.0, 20.0, 20.0)) > 1.0  # the red patch: all target colours
    # The road in the box's corners is not the target's: a box of road and grass holds none of its colours.
    assert anchor.share(frame, (0.0, 0.0, 40.0, 40.0)) == 0.0
    assert anchor.share(frame, (62.0, 42.0, 8.0, 36.0)) == 0.0  # the road strip left of the target
    assert anchor.share(frame, (400.0, 400.0, 10.0, 10.0)) == 0.0  # outside the frame


def test_a_target_without_colours_of_its_own_has_no_anchor():
    frame = np.full((120, 160, 3), GREY, np.uint8)
    frame[50:70, 70:90] = (140, 140, 140)  # grey on grey: the same histogram bin
    anchor = _anchor(frame, (65.0, 45.0, 30.0, 30.0))
    assert not anchor.usable and anchor.share(frame, (0.0, 0.0, 20.0, 20.0)) == math.inf
    frame = _loose_box_scene()
    assert not _anchor(frame, min_reference=1.01).usable  # its own colours must cover min_reference of it


@pytest.mark.parametrize("key, value", [("drift_share", 1.0), ("drift_frames", 0), ("anchor_inner", 0.0),
                                        ("clear_share", 0.05), ("checkpoint_frames", 0), ("clear_bar_fraction", 0.0),
                                        ("anchor_min_share", 1.5)])
def test_drift_check_parameters_are_validated_by_name(key, value):
    with pytest.raises(ValueError, match=rf"redetect\.colour\.{key}"):
        RedetectParams.from_mapping({"colour": {key: value}})


def test_hue_histogram_bins_by_hue_and_saturation_and_puts_greys_apart():
    red, dark_red, grey, pale = (0, 0, 220), (0, 0, 110), (128, 128, 128), (200, 200, 220)
    counts = hue_histogram(np.array([red, dark_red, grey, pale], np.uint8))
    assert counts.shape == (HUES * SATURATIONS + GREYS,) and counts.sum() == pytest.approx(1.0)
    assert counts[SATURATIONS - 1] == pytest.approx(0.5)  # red, bright or in shade: hue 0, saturated
    assert counts[HUES * SATURATIONS:].sum() == pytest.approx(0.5)  # grey and a pale tint: no hue
    grey_frame = hue_histogram(np.array([0, 255], np.uint8))  # a grey frame's pixels: the grey levels alone
    assert grey_frame.shape == counts.shape and grey_frame[DARK_BIN:].tolist() == [0.5, 0.0, 0.0, 0.5]
    assert hue_histogram(np.empty((0, 3), np.uint8)) is None


def test_the_anchor_keeps_a_target_in_shade():
    frame = _loose_box_scene()
    anchor = _anchor(frame)
    shaded = frame.copy()
    shaded[40:80, 60:100] = (shaded[40:80, 60:100] * 0.5).astype(np.uint8)  # the target and its road at half light
    assert anchor.share(shaded, LOOSE) == pytest.approx(1.0)


def test_jsar_re_tracks_a_grey_frame():
    """A grey camera (H x W frames) is tracked, the drift check reading grey levels (found by the Zenoh
    fuzzer: the dark bin lay past a grey histogram's end, so init raised IndexError)."""
    rng = np.random.default_rng(0)
    frame = (rng.random((120, 160)) * 255).astype(np.uint8)
    frame[40:70, 60:90] = 230
    tracker = jsar.create("jsar-re")
    tracker.init(frame, (60.0, 40.0, 30.0, 30.0))
    for _ in range(5):
        result = tracker.update(frame)
        assert result.state == "tracking" and abs(result.box[0] - 60.0) < 2 and abs(result.box[1] - 40.0) < 2
