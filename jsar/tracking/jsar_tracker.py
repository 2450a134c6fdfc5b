"""JSAR (STRCF translation filter + joint scale x aspect-ratio size filter) and the STRCF baseline.

Coordinates: continuous pixels, pixel k covers [k, k+1); boxes (x, y, w, h), top-left origin;
the centre is (x + w/2, y + h/2). `result.score` is the raw translation response peak in the
MATLAB FFT convention (forward unnormalised, inverse 1/N; see jsar.fourier), the unit of the
JSAR-Re thresholds.

Step API (JSAR-Re composes it): `locate` (detection only, no state change) -> `commit`
(accept: move, estimate size, train) or `reinitialise` (retrain from scratch at a new box).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from jsar import dcf, fourier
from jsar.api import Box, TrackResult, validate_box, validate_frame
from jsar.config import JsarParams
from jsar.features import colour, patches
from jsar.features import translation as translation_features
from jsar.tracking.size_filter import (SizeFilter, best_cell, bound_side, clamp_size, refined_position,
                                       updated_mean)
from jsar.tracking.translation import TranslationFilter


@dataclass(frozen=True)
class Localisation:
    """One detection: where the target is now, how confident, and the sample it was found in.

    centre_xy: new centre (px); peak: raw translation response maximum; displacement_cells:
    (dy, dx) found in the feature map; sample_f: the detection sample's spectrum (C, H, W//2+1)
    (reused for training); search_side: side (px) of the square it was cut from; scale_factor:
    size factor of the chosen search scale (STRCF's multi-scale search; 1.0 for JSAR);
    response: the (H, W) response map (cells, peak position = displacement, wrapped).
    """

    centre_xy: tuple[float, float]
    peak: float
    displacement_cells: tuple[float, float]
    sample_f: np.ndarray
    search_side: float
    scale_factor: float
    response: np.ndarray


class JsarTracker:
    """JSAR: `init(frame, box)`, `update(frame) -> TrackResult`, plus the step API.

    `use_size_filter=False` gives the STRCF baseline: the same translation filter evaluated
    on `strcf_num_scales` scaled search samples (step `strcf_scale_step`), the best peak wins,
    aspect ratio fixed.
    """

    def __init__(self, params: JsarParams | None = None, *, use_size_filter: bool = True):
        self.params = params if params is not None else JsarParams()
        self.params.validate()
        self.use_size_filter = use_size_filter
        self._colour_table: np.ndarray | None = None
        if self.params.use_colour:
            self._colour_table = (colour.load_colour_table(self.params.colour_table_path)
                                  if self.params.colour_table_path else colour.derived_colour_table())
        self._initialised = False
        self.frame_index = -1  # frames seen since init (0 = the init frame)
        self.last_training_sample_f: np.ndarray | None = None  # (C, H, W//2+1), see class doc
        self.last_localisation: Localisation | None = None
        self._side_bounds: tuple[float, float] | None = None

    # ----------------------------------------------------------------- public API
    def init(self, frame: np.ndarray, box: Box) -> None:
        """Start tracking `box` (x, y, w, h px) in `frame` (HxWx3 BGR or HxW uint8)."""
        frame = validate_frame(frame)
        box = validate_box(box, frame.shape)
        self._grey = frame.ndim == 2 or _is_grey(frame) or self._colour_table is None
        self.frame_index = 0
        self._initial_ratio = box[2] / box[3]
        self._side_bounds = None
        self._setup(self._prepare(frame), box)

    def set_side_bounds(self, side_bounds_px: tuple[float, float] | None) -> None:
        """Bound the box side sqrt(w*h) to (lo, hi) px from the next size estimate on (None: unbounded).

        For a size known from outside the image, e.g. a ground target's range from the vehicle's
        altitude and the camera's pointing (the service does this): the size filter models scale and
        aspect, not in-plane rotation, and shrinks the box of a target that keeps turning. The bound
        holds until changed; init() clears it (a new target).
        """
        if side_bounds_px is not None:
            lo, hi = (float(v) for v in side_bounds_px)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
                raise ValueError(f"side bounds must be finite with 0 < lo <= hi px, got {side_bounds_px}")
            side_bounds_px = (lo, hi)
        self._side_bounds = side_bounds_px

    @property
    def side_bounds(self) -> tuple[float, float] | None:
        """The current (lo, hi) px bounds on sqrt(w*h), or None."""
        return self._side_bounds

    def update(self, frame: np.ndarray) -> TrackResult:
        """Track one frame: locate, then commit; returns the new box and the response peak."""
        image = self._prepare_checked(frame)
        loc = self.locate(image)
        self.commit(image, loc)
        return TrackResult(box=self.box, score=loc.peak, state="tracking")

    @property
    def box(self) -> Box:
        """Current target box (x, y, w, h) in pixels."""
        cx, cy = self.centre_xy
        w, h = self.size_wh
        return (cx - w / 2.0, cy - h / 2.0, w, h)

    # ----------------------------------------------------------------- step API
    def locate(self, frame: np.ndarray) -> Localisation:
        """Detect the target in `frame` around the current position; changes no state."""
        image = self._prepare_checked(frame)
        p = self.params
        base_side = self._search_side()
        if self.use_size_filter:
            factors = [1.0]
        else:
            count = p.strcf_num_scales
            factors = [p.strcf_scale_step ** (k - (count - 1) / 2.0) for k in range(count)]
        best: Localisation | None = None
        for factor in factors:
            side = base_side * factor
            sample_f = self._sample_spectrum(image, self.centre_xy, side)
            resp, resp_f = self.translation.response(sample_f)
            dy, dx, peak = dcf.subpixel_peak(resp, resp_f, p.newton_iterations)
            if best is None or peak > best.peak:
                px_per_cell = side / self._cells
                centre = (self.centre_xy[0] + dx * px_per_cell, self.centre_xy[1] + dy * px_per_cell)
                best = Localisation(centre, peak, (dy, dx), sample_f, side, factor, resp)
        assert best is not None
        return best

    def commit(self, frame: np.ndarray, loc: Localisation, learn_size: bool = True) -> None:
        """Accept `loc`: move there, estimate the size, train both filters from that sample (learn_size False:
        the size filter estimates but does not learn, nor sample the new size's grid to learn from)."""
        image = self._prepare_checked(frame)
        height, width = image.shape[:2]
        # Keep the centre on the image: a target leaving the view is followed to the border.
        cx = min(max(loc.centre_xy[0], 0.0), float(width))
        cy = min(max(loc.centre_xy[1], 0.0), float(height))
        self.centre_xy = (cx, cy)
        if self.use_size_filter:
            self._update_size(image, learn_size)
        else:
            w, h = self.size_wh
            self.size_wh = self._clamp((w * loc.scale_factor, h * loc.scale_factor), image)
        # Training sample: the detection sample re-centred on the found position (no second crop).
        dy, dx = loc.displacement_cells
        sample_f = loc.sample_f * fourier.shift_phase(self.translation.shape_hw, dy, dx)[None]
        self.translation.set_target_cells(self._target_cells())
        self.translation.train(sample_f)
        self.last_training_sample_f = sample_f
        self.last_localisation = loc
        self.frame_index += 1

    def reinitialise(self, frame: np.ndarray, box: Box) -> None:
        """Retrain everything from scratch at `box` (once: later frames update normally)."""
        image = self._prepare_checked(frame)
        box = validate_box(box, image.shape)
        self._setup(image, box)

    def relocate(self, centre_xy: tuple[float, float]) -> None:
        """Move the target's centre to centre_xy px, keeping the size and every filter as they are
        (the target was found again elsewhere; nothing is learnt from this frame)."""
        if not self._initialised:
            raise RuntimeError("tracker used before init(frame, box)")
        cx, cy = (float(v) for v in centre_xy)
        if not (math.isfinite(cx) and math.isfinite(cy)):
            raise ValueError(f"centre must be finite, got {centre_xy}")
        self.centre_xy = (cx, cy)

    def hold_size_until_recognised(self, fraction: float) -> None:
        """Keep the size (the size filter still learns each frame at it) until the size filter's
        response peak reaches `fraction` x the running mean of its peaks (rate params.size_peak_rate,
        every frame, so a hold ends within a few frames even if the level stays low). For a target
        found again after a loss: the size model of its old look misjudges a target that came back
        turned and can widen its box frame after frame."""
        if not 0.0 < fraction < 1.0:
            raise ValueError(f"fraction must be in (0, 1), got {fraction}")
        self.size_hold_fraction = fraction

    def target_cells(self) -> tuple[float, float]:
        """Target (h, w) in feature cells of the translation filter's search patch."""
        return self._target_cells()

    def prepare(self, frame: np.ndarray) -> np.ndarray:
        """`frame` validated and converted to the tracker's mode (2-D grey or HxWx3 BGR)."""
        return self._prepare_checked(frame)

    @property
    def feature_colour_table(self) -> np.ndarray | None:
        """The colour-attribute table the translation features use (None in grey mode)."""
        return None if self._grey else self._colour_table

    def sample_spectrum(self, frame: np.ndarray, centre_xy: tuple[float, float], side: float) -> np.ndarray:
        """Windowed feature spectrum (C, H, W//2+1) of the square of side `side` px at `centre_xy`,
        exactly as the translation filter sees its samples (e.g. to score re-detection proposals)."""
        return self._sample_spectrum(self._prepare_checked(frame), centre_xy, side)

    # ----------------------------------------------------------------- internals
    def _setup(self, image: np.ndarray, box: Box) -> None:
        """Fresh filters for `box` on `image`, trained on that frame (first-frame rules: mu = 0)."""
        p = self.params
        x, y, w, h = box
        self.centre_xy = (x + w / 2.0, y + h / 2.0)
        self._min_side = min(p.min_target_side_px, w, h)
        self.size_wh = (w, h)
        self._cells = p.search_patch_px // p.cell_size
        self.translation = TranslationFilter(p, (self._cells, self._cells), self._target_cells())
        self.size_filter = SizeFilter(p, (w, h)) if self.use_size_filter else None
        self.size_peak_mean: float | None = None  # running mean of the size filter's response peaks
        self.size_hold_fraction: float | None = None  # see hold_size_until_recognised
        sample_f = self._sample_spectrum(image, self.centre_xy, self._search_side())
        self.translation.train(sample_f)
        self.last_training_sample_f = sample_f
        if self.size_filter is not None:
            size_sample = self.size_filter.sample(image, self.centre_xy, self.size_wh)
            self.size_filter.train(self.size_filter.spectrum(size_sample))
        self._initialised = True

    def _update_size(self, image: np.ndarray, learn: bool = True) -> None:
        """Estimate scale and aspect at the new centre; train the size filter at the new size (at the
        old one during a hold: hold_size_until_recognised; not at all with learn False)."""
        assert self.size_filter is not None
        sample = self.size_filter.sample(image, self.centre_xy, self.size_wh)
        sample_f = self.size_filter.spectrum(sample)
        resp = self.size_filter.response(sample_f)
        peak, mean = float(resp.max()), self.size_peak_mean
        self.size_peak_mean = updated_mean(mean, peak, self.params.size_peak_rate)
        if self.size_hold_fraction is not None:
            if mean is not None and peak < self.size_hold_fraction * mean:
                if learn:
                    self.size_filter.train(sample_f)
                return
            self.size_hold_fraction = None  # recognised: estimate from here on
        if self.params.size_subcell_peak:
            # A fractional step: the new grid shares no cell with the old one, so sample it afresh.
            fw, fh = self.size_filter.cell_factors(*refined_position(resp, self.params.size_deadband_cells))
            w, h = self.size_wh
            new_size = self._clamp((w * fw, h * fh), image)
            if learn and new_size != self.size_wh:
                sample_f = self.size_filter.spectrum(self.size_filter.sample(image, self.centre_xy, new_size))
            self.size_wh = new_size
            if learn:
                self.size_filter.train(sample_f)
            return
        i, j = best_cell(resp)
        fw, fh = self.size_filter.cell_factors(i, j)
        w, h = self.size_wh
        grid_size = (w * fw, h * fh)
        new_size = self._clamp(grid_size, image)
        if not learn:
            self.size_wh = new_size
            return
        if new_size != self.size_wh:
            centre_i = (self.size_filter.grid_shape[0] - 1) // 2
            centre_j = (self.size_filter.grid_shape[1] - 1) // 2
            if new_size == grid_size:
                # The new grid is the old one shifted by (i - c, j - c) cells around the same
                # centre: reuse the overlap, sample only the cells that enter the grid.
                sample = self.size_filter.shifted_sample(
                    image, self.centre_xy, new_size, sample, (i - centre_i, j - centre_j))
            else:  # clamped: not on the old grid, sample it afresh
                sample = self.size_filter.sample(image, self.centre_xy, new_size)
            self.size_wh = new_size
            sample_f = self.size_filter.spectrum(sample)
        self.size_filter.train(sample_f)

    def _clamp(self, size_wh: tuple[float, float], image: np.ndarray) -> tuple[float, float]:
        band = self.params.aspect_band
        return clamp_size(bound_side(size_wh, self._side_bounds), self._min_side, (image.shape[1], image.shape[0]),
                          (self._initial_ratio / band, self._initial_ratio * band))

    def _search_side(self) -> float:
        """Side (px) of the square search region: factor * sqrt(w * h)."""
        w, h = self.size_wh
        return self.params.search_area_factor * math.sqrt(w * h)

    def _target_cells(self) -> tuple[float, float]:
        """Target (h, w) in feature cells of the search patch."""
        w, h = self.size_wh
        cells_per_px = self._cells / self._search_side()
        return h * cells_per_px, w * cells_per_px

    def _sample_spectrum(self, image: np.ndarray, centre_xy: tuple[float, float], side: float) -> np.ndarray:
        """Spectrum (C, H, W//2+1) of the windowed features of the square search patch."""
        out = self.params.search_patch_px
        patch = patches.sample_patch(image, centre_xy, (side, side), (out, out))
        table = None if self._grey else self._colour_table
        feats = translation_features.extract_features(patch, self.params.cell_size, table)
        return self.translation.sample_spectrum(feats)

    def _prepare(self, frame: np.ndarray) -> np.ndarray:
        """The frame in the tracker's mode: 2-D grey in grey mode, HxWx3 BGR in colour mode."""
        if self._grey:
            return frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        return frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)

    def _prepare_checked(self, frame: np.ndarray) -> np.ndarray:
        if not self._initialised:
            raise RuntimeError("tracker used before init(frame, box)")
        frame = validate_frame(frame)
        expected_ndim = 2 if self._grey else 3
        return frame if frame.ndim == expected_ndim else self._prepare(frame)


def _is_grey(frame: np.ndarray) -> bool:
    """True if a HxWx3 frame has R == G == B everywhere (a grey video decoded as BGR)."""
    return bool(np.array_equal(frame[:, :, 0], frame[:, :, 1]) and np.array_equal(frame[:, :, 1], frame[:, :, 2]))


def make_jsar(**overrides: Any) -> JsarTracker:
    """Registry factory for "jsar": JSAR defaults with `overrides` (ValueError on unknown keys)."""
    return JsarTracker(JsarParams().with_overrides(**overrides), use_size_filter=True)


def make_strcf(**overrides: Any) -> JsarTracker:
    """Registry factory for "strcf": the translation filter with STRCF's 5-scale search."""
    return JsarTracker(JsarParams().with_overrides(**overrides), use_size_filter=False)
