"""The joint scale x aspect-ratio size filter: grid geometry, clamps, and estimates on a synthetic target."""
from __future__ import annotations

import numpy as np
import pytest

from jsar.config import JsarParams
from jsar.tracking.size_filter import (SizeFilter, best_cell, bound_side, clamp_size, grid_label, grid_sizes, model_size,
                                       refined_position)


def test_grid_is_symmetric_and_its_centre_is_the_current_size():
    params = JsarParams()
    sizes = grid_sizes((40.0, 20.0), params)
    assert sizes.shape == (13, 13, 2)
    np.testing.assert_allclose(sizes[6, 6], (40.0, 20.0))
    for i, j in [(0, 0), (2, 9), (12, 5)]:
        mirror = sizes[12 - i, 12 - j]
        np.testing.assert_allclose(sizes[i, j] * mirror, np.array([40.0, 20.0]) ** 2, rtol=1e-9)
    # Scale axis keeps the w/h ratio; aspect axis keeps the area and changes w/h by phi^2 per cell.
    ratio = sizes[..., 0] / sizes[..., 1]
    np.testing.assert_allclose(ratio[:, 6], 2.0)
    np.testing.assert_allclose(ratio[6, 7] / ratio[6, 6], 1.02**2)
    area = sizes[..., 0] * sizes[..., 1]
    np.testing.assert_allclose(area[6, :], 800.0)
    np.testing.assert_allclose(area[7, 6] / area[6, 6], 1.03**2)


def test_grid_label_peaks_at_the_centre_with_wider_aspect_sigma_for_jsar_re():
    label = grid_label(JsarParams())
    assert np.unravel_index(np.argmax(label), label.shape) == (6, 6)
    re_label = grid_label(JsarParams.jsar_re())
    assert re_label[6, 0] > label[6, 0] and re_label[0, 6] == pytest.approx(label[0, 6])


def test_model_size_keeps_aspect_caps_area_and_keeps_tiny_targets_at_two_cells():
    assert model_size((100, 50), 512, 8, 4) == (32, 16)
    assert model_size((20, 10), 512, 8, 4) == (20, 12) or model_size((20, 10), 512, 8, 4) == (20, 8)
    assert model_size((6, 7), 512, 8, 4) == (8, 8)


def test_clamp_size_keeps_small_targets_and_bounds_the_ratio_band_both_ways():
    assert clamp_size((6.0, 7.0), 3.0, (1280, 720), (0.25, 4.0)) == (6.0, 7.0)
    w, h = clamp_size((2.0, 2.5), 3.0, (1280, 720), (0.2, 5.0))
    assert (w, h) == (3.0, 3.0)
    w, h = clamp_size((100.0, 10.0), 3.0, (1280, 720), (0.5, 2.0))  # ratio 10 -> 2, area kept
    assert w / h == pytest.approx(2.0) and w * h == pytest.approx(1000.0)
    w, h = clamp_size((10.0, 100.0), 3.0, (1280, 720), (0.5, 2.0))  # ratio 0.1 -> 0.5
    assert w / h == pytest.approx(0.5)
    assert clamp_size((2000.0, 50.0), 3.0, (1280, 720), (0.01, 100.0))[0] == 1280.0


def _scene(target_wh: tuple[float, float], center=(160.0, 120.0)) -> np.ndarray:
    """A 320x240 grey scene: a bright box of size target_wh with a dark inner box, centred at `center`."""
    ys, xs = np.mgrid[0:240, 0:320].astype(np.float64) + 0.5
    u = np.abs(xs - center[0]) / (target_wh[0] / 2)  # 1 on the target's border
    v = np.abs(ys - center[1]) / (target_wh[1] / 2)
    frame = np.where((u < 1) & (v < 1), 210.0, 40.0)
    frame = np.where((u < 0.45) & (v < 0.45), 90.0, frame)
    return frame.astype(np.uint8)


@pytest.mark.parametrize("scale, stretch", [(1.09, 1.0), (1 / 1.09, 1.0), (1.0, 1.06), (1.0, 1 / 1.06)])
def test_size_filter_estimates_scale_and_aspect_change_in_the_right_direction(scale, stretch):
    params = JsarParams()
    size = (48.0, 40.0)
    sf = SizeFilter(params, size)
    sf.train(sf.spectrum(sf.sample(_scene(size), (160.0, 120.0), size)))
    new_size = (size[0] * scale * stretch, size[1] * scale / stretch)
    i, j = best_cell(sf.response(sf.spectrum(sf.sample(_scene(new_size), (160.0, 120.0), size))))
    # Scale index moves with the area change only, aspect index with the ratio change only.
    assert np.sign(i - 6) == np.sign(round(np.log(scale), 6))
    assert np.sign(j - 6) == np.sign(round(np.log(stretch), 6))
    fw, fh = sf.cell_factors(i, j)
    assert np.sign(np.log(fw * fh)) == np.sign(round(np.log(scale), 6))


@pytest.mark.parametrize("center", [(200.3, 150.7), (3.0, 4.0), (398.0, 297.0), (-30.0, 150.0), (-500.0, -500.0)])
def test_grey_region_samples_exactly_like_the_full_grey_frame(center):
    import cv2

    from jsar.features import patches
    from jsar.tracking.size_filter import grey_region

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (300, 400, 3)).astype(np.uint8)
    sizes = grid_sizes((50.0, 40.0), JsarParams()).reshape(-1, 2)
    crop, local_center = grey_region(image, center, sizes.max(axis=0))
    via_crop = patches.sample_patches(crop, local_center, sizes, (24, 20))
    full = patches.sample_patches(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), center, sizes, (24, 20))
    np.testing.assert_array_equal(via_crop, full)


def test_grid_spectrum_equals_rfft2_over_the_grid_axes():
    import scipy.fft

    sf = SizeFilter(JsarParams(), (40.0, 30.0))
    sample = np.random.default_rng(1).standard_normal((13, 13, 50)).astype(np.float32)
    expected = scipy.fft.rfft2(sample, axes=(0, 1))
    np.testing.assert_allclose(sf.spectrum(sample), expected, atol=2e-4)


@pytest.mark.parametrize("shift", [(1, 0), (0, -1), (-1, 1), (2, -2)])
def test_shifted_sample_equals_a_fresh_sample_at_the_new_size(shift):
    params = JsarParams()
    sf = SizeFilter(params, (48.0, 40.0))
    frame = _scene((50.0, 38.0))
    old = sf.sample(frame, (160.0, 120.0), (48.0, 40.0))
    fw, fh = sf.cell_factors(6 + shift[0], 6 + shift[1])
    new_size = (48.0 * fw, 40.0 * fh)
    shifted = sf.shifted_sample(frame, (160.0, 120.0), new_size, old, shift)
    fresh = sf.sample(frame, (160.0, 120.0), new_size)
    np.testing.assert_allclose(shifted, fresh, atol=1e-5)


def test_parabola_offset_finds_the_vertex_and_ignores_non_maxima():
    from jsar.tracking.size_filter import parabola_offset

    assert parabola_offset(0.5, 1.0, 0.5) == 0.0
    # y = -(x - 0.25)^2 sampled at -1, 0, 1.
    assert parabola_offset(-1.5625, -0.0625, -0.5625) == pytest.approx(0.25)
    assert parabola_offset(-0.5625, -0.0625, -1.5625) == pytest.approx(-0.25)
    assert parabola_offset(1.0, 0.5, 1.0) == 0.0  # a minimum is not refined
    assert parabola_offset(0.0, 1.0, 1.0) == 0.5  # clamped to half a cell


def test_refined_position_moves_continuously_where_the_best_cell_does_not():
    """A car scaled by 1.03^e (e grid steps): the refined scale position moves the right way, further
    for a larger change, already at one step, where the best cell is still the centre. (One frame's
    estimate is a fraction of the change: the label is nearly flat; frames accumulate it.)"""
    size, centre = (90.0, 40.0), (320.0, 240.0)
    sf = SizeFilter(JsarParams.jsar_re(), size)
    sf.train(sf.spectrum(sf.sample(_textured_scene(size), centre, size)))
    for sign in (-1.0, 1.0):
        moves = []
        for steps in (1, 2, 3):
            scaled = (size[0] * 1.03 ** (sign * steps), size[1] * 1.03 ** (sign * steps))
            spectrum = sf.spectrum(sf.sample(_textured_scene(scaled), centre, size))
            i, j = refined_position(sf.response(spectrum))
            moves.append(sign * (i - 6))
            assert abs(j - 6) < 0.5, "a pure scale change must not move the aspect estimate far"
            if steps == 1:
                assert best_cell(sf.response(spectrum))[0] == 6
        assert 0 < moves[0] < moves[1] < moves[2], moves


def test_refined_position_deadband_ignores_offsets_below_it_per_axis():
    """size_deadband_cells: a refined offset from the grid centre below the band counts as none (the
    centre cell); a larger one is kept, fractional; 0 (the default) keeps every offset."""
    size, centre = (90.0, 40.0), (320.0, 240.0)
    sf = SizeFilter(JsarParams.jsar_re(), size)
    sf.train(sf.spectrum(sf.sample(_textured_scene(size), centre, size)))
    scaled = (size[0] * 1.03 ** 2, size[1] * 1.03 ** 2)
    spectrum = sf.spectrum(sf.sample(_textured_scene(scaled), centre, size))
    response = sf.response(spectrum)
    i, j = refined_position(response)
    assert abs(j - 6) < 0.5 < abs(i - 6)  # two scale steps: the best cell has moved; aspect has not
    band_i, band_j = refined_position(response, deadband_cells=0.5)
    assert band_j == 6.0 and band_i == pytest.approx(i)  # the scale offset is beyond the band, kept
    assert refined_position(response, deadband_cells=abs(i - 6) + 0.01) == (6.0, 6.0)
    with pytest.raises(ValueError, match="size_deadband_cells"):
        JsarParams(size_deadband_cells=-0.1).validate()


def _textured_scene(target_wh: tuple[float, float], angle_deg: float = 0.0) -> np.ndarray:
    """640x480 BGR frame: a fixed random ground texture and a red 'car' with dark windows of
    (length, width) target_wh px, turned by angle_deg about the image centre."""
    import cv2

    rng = np.random.default_rng(7)
    ground = cv2.GaussianBlur(rng.integers(40, 140, (480, 640, 3)).astype(np.uint8), (0, 0), 3)
    car = np.full((60, 90, 3), (40, 40, 200), np.uint8)  # a red body with two dark windows
    car[8:52, 18:30] = car[8:52, 60:72] = (30, 30, 30)
    length, width = target_wh
    # car texture (90 x 60 px) -> scaled to length x width, turned, centred on (320, 240)
    scale = np.diag([length / 90.0, width / 60.0])
    c, s_ = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    turn = np.array([[c, s_], [-s_, c]])
    linear = turn @ scale
    affine = np.hstack([linear, (np.array([320.0, 240.0]) - linear @ np.array([45.0, 30.0]))[:, None]])
    warped = cv2.warpAffine(car, affine, (640, 480), flags=cv2.INTER_AREA)
    mask = cv2.warpAffine(np.full((60, 90), 255, np.uint8), affine, (640, 480))
    frame = np.where(mask[..., None] > 127, warped, ground)
    return frame


def test_tracker_box_follows_a_shrinking_target_with_the_default_size_estimate():
    """A car shrinking 0.5 % per frame (a sixth of a grid step) for 120 frames: the sub-cell path
    (fractional steps, fresh grid sample for training) ends within 12 % of its size, both sides."""
    from jsar.tracking.jsar_tracker import JsarTracker

    params = JsarParams.jsar_re()
    assert params.size_subcell_peak
    tracker = JsarTracker(params)
    tracker.init(_textured_scene((90.0, 40.0)), (275.0, 220.0, 90.0, 40.0))
    for k in range(1, 121):
        box = tracker.update(_textured_scene((90.0 * 0.995**k, 40.0 * 0.995**k))).box
    assert box[2] / (90.0 * 0.995**120) == pytest.approx(1.0, abs=0.12)
    assert box[3] / (40.0 * 0.995**120) == pytest.approx(1.0, abs=0.12)


def _tracked_car(frames: int = 8):
    """A JSAR-Re core that tracked the upright car (90 x 40 px at the image centre) for `frames` frames."""
    from jsar.tracking.jsar_tracker import JsarTracker

    tracker = JsarTracker(JsarParams.jsar_re())
    tracker.init(_textured_scene((90.0, 40.0)), (275.0, 220.0, 90.0, 40.0))
    for _ in range(frames):
        tracker.update(_textured_scene((90.0, 40.0)))
    return tracker


def test_a_size_hold_keeps_the_size_while_the_size_filter_does_not_recognise_the_target_and_it_learns():
    """The car turned 90 degrees (as after a loss): its size filter's peak falls under 0.75 x its running
    mean, so the size is kept on those frames while the filter learns them; the hold ends by itself (the
    mean follows the lower peaks), after which the size is estimated again."""
    tracker = _tracked_car()
    turned = _textured_scene((90.0, 40.0), angle_deg=90.0)
    tracker.hold_size_until_recognised(0.75)
    size, numerator = tracker.size_wh, tracker.size_filter.numerator.copy()
    held_frames = 0
    while tracker.size_hold_fraction is not None and held_frames < 40:
        mean = tracker.size_peak_mean
        tracker.update(turned)
        if tracker.size_hold_fraction is not None:
            held_frames += 1
            assert tracker.size_wh == size  # kept ...
            assert tracker.size_peak_mean < mean  # ... while the mean follows the lower peaks
    assert 1 <= held_frames < 40, held_frames
    assert not np.array_equal(tracker.size_filter.numerator, numerator)  # it learnt the turned car


def test_a_size_hold_on_a_recognised_target_ends_at_once_and_changes_nothing():
    """Where the size filter recognises the target the hold ends on the first frame, with the same box as
    without it: the hold costs nothing when the target looks as before."""
    held, free = _tracked_car(), _tracked_car()
    held.hold_size_until_recognised(0.75)
    smaller = _textured_scene((85.0, 38.0))
    assert held.update(smaller).box == free.update(smaller).box
    assert held.size_hold_fraction is None and held.box != (275.0, 220.0, 90.0, 40.0)
    with pytest.raises(ValueError, match="fraction"):
        held.hold_size_until_recognised(1.0)


def test_bound_side_scales_about_the_aspect_ratio_into_the_bounds():
    assert bound_side((40.0, 10.0), None) == (40.0, 10.0)
    assert bound_side((40.0, 10.0), (10.0, 30.0)) == (40.0, 10.0)  # side 20: inside
    w, h = bound_side((40.0, 10.0), (30.0, 60.0))  # side 20 -> 30, w/h 4 kept
    assert np.sqrt(w * h) == pytest.approx(30.0) and w / h == pytest.approx(4.0)
    w, h = bound_side((40.0, 10.0), (5.0, 10.0))  # side 20 -> 10
    assert np.sqrt(w * h) == pytest.approx(10.0) and w / h == pytest.approx(4.0)


def test_side_bounds_hold_the_box_of_a_shrinking_target_and_init_clears_them():
    """The same car shrinking 0.5 % per frame to 0.55x: bounded at 0.8x its first side, the box
    stops there (aspect ratio still estimated); unbounded it follows the car down (test above)."""
    from jsar.tracking.jsar_tracker import JsarTracker

    tracker = JsarTracker(JsarParams.jsar_re())
    first = _textured_scene((90.0, 40.0))
    tracker.init(first, (275.0, 220.0, 90.0, 40.0))
    side0 = 60.0  # sqrt(90 * 40)
    tracker.set_side_bounds((0.8 * side0, 2.0 * side0))
    sides = []
    for k in range(1, 121):
        box = tracker.update(_textured_scene((90.0 * 0.995**k, 40.0 * 0.995**k))).box
        sides.append(np.sqrt(box[2] * box[3]))
    assert min(sides) >= 0.8 * side0 - 1e-6
    assert sides[-1] == pytest.approx(0.8 * side0, rel=1e-6)  # held at the bound, not somewhere above it
    assert tracker.side_bounds == (0.8 * side0, 2.0 * side0)
    tracker.init(first, (275.0, 220.0, 90.0, 40.0))
    assert tracker.side_bounds is None


@pytest.mark.parametrize("bounds", [(0.0, 10.0), (20.0, 10.0), (float("nan"), 10.0), (1.0, float("inf"))])
def test_side_bounds_reject_empty_or_non_finite_ranges(bounds):
    from jsar.tracking.jsar_tracker import JsarTracker

    with pytest.raises(ValueError, match="side bounds"):
        JsarTracker().set_side_bounds(bounds)


@pytest.mark.parametrize("reacquire", ["relocate", "retrain"])
def test_jsar_re_reacquires_within_the_side_bounds(reacquire):
    """A re-acquisition keeps the box side within the bounds (here above the last confident side of
    60 px) and the last aspect ratio: "retrain" re-initialises there, centred on the candidate;
    "relocate" moves the filters there and commits that frame (which finds the car itself)."""
    from jsar.redetect.jsar_re import JsarReTracker
    from jsar.redetect.params import RedetectParams
    from jsar.redetect.search import Candidate

    tracker = JsarReTracker(redetect=RedetectParams.from_mapping({"accept": {"reacquire": reacquire}}))
    frame = _textured_scene((90.0, 40.0))
    tracker.init(frame, (275.0, 220.0, 90.0, 40.0))
    tracker.set_side_bounds((70.0, 80.0))
    tracker._reacquire(frame, Candidate(330.0, 245.0, 1.0))  # 10, 5 px off the car's centre (320, 240)
    x, y, w, h = tracker.core.box
    assert np.sqrt(w * h) == pytest.approx(70.0) and w / h == pytest.approx(90.0 / 40.0, rel=0.01)
    centre = (x + w / 2, y + h / 2)
    if reacquire == "retrain":
        assert centre == pytest.approx((330.0, 245.0))
    else:
        assert np.hypot(centre[0] - 320.0, centre[1] - 240.0) < 2.0
    assert tracker.reacquisitions == 1 and tracker.monitor.reference is None
    # "relocate" keeps the core's size model, so its size is held until that model recognises the car
    # (here at once: the same car); "retrain" trains a new one on this frame.
    assert tracker.core.size_hold_fraction is None


def test_a_relocated_take_holds_the_size_until_the_size_filter_recognises_the_target():
    """The take's frame shows the car turned by 30 degrees (a relocated core still finds it; at 45 the
    core is retrained there): the relocated core keeps its size and stays on hold;
    with accept.size_hold_fraction 0 its old size model estimates a new size on that frame."""
    from jsar.redetect.jsar_re import JsarReTracker
    from jsar.redetect.params import RedetectParams
    from jsar.redetect.search import Candidate

    sizes = {}
    for fraction in (0.75, 0.0):
        tracker = JsarReTracker(redetect=RedetectParams.from_mapping({"accept": {"size_hold_fraction": fraction}}))
        upright = _textured_scene((90.0, 40.0))
        tracker.init(upright, (275.0, 220.0, 90.0, 40.0))
        for _ in range(8):
            tracker.update(upright)
        before = tracker.core.size_wh
        tracker._reacquire(_textured_scene((90.0, 40.0), angle_deg=30.0), Candidate(320.0, 240.0, 1.0))
        sizes[fraction] = (before, tracker.core.size_wh, tracker.core.size_hold_fraction)
    before, after, hold = sizes[0.75]
    assert after == before and hold == 0.75
    before, after, hold = sizes[0.0]
    assert after != before and hold is None


def test_a_commit_that_does_not_learn_the_size_estimates_it_as_one_that_does_and_leaves_the_size_model():
    """commit(..., learn_size=False) (a coasting JSAR-Re core: the target may be hidden): the same size estimate as a
    learning commit on the same frame, the size filter's model untouched; the translation filter still learns."""
    learning, estimating = _tracked_car(), _tracked_car()
    smaller = _textured_scene((80.0, 36.0))
    numerator, filter_f = estimating.size_filter.numerator.copy(), estimating.translation.filter_f.copy()
    learning.commit(smaller, learning.locate(smaller))
    estimating.commit(smaller, estimating.locate(smaller), learn_size=False)
    assert estimating.size_wh == learning.size_wh != (90.0, 40.0)
    np.testing.assert_array_equal(estimating.size_filter.numerator, numerator)
    assert not np.array_equal(learning.size_filter.numerator, numerator)
    assert not np.array_equal(estimating.translation.filter_f, filter_f)
