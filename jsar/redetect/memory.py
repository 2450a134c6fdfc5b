"""The decision filter: JSAR-Re's long-term memory of the target's reliable appearances.

A second STRCF translation filter (same features, geometry and solver as the core's), trained only
on reliable committed frames, never on a lost frame. It scores:
- the core tracker's own detection sample every frame (no extra features: one spectral product);
- windows of its sample geometry anywhere in the frame (the search while lost).
Scores are raw response peaks (MATLAB FFT convention, the paper's eta_d unit); positions full-frame
pixels. `reference` is the running mean of its peaks on the samples it trains on.
"""
from __future__ import annotations

import concurrent.futures
import math

import cv2
import numpy as np

from jsar import dcf, fourier
from jsar.config import JsarParams
from jsar.features import patches
from jsar.features import translation as translation_features
from jsar.redetect.monitor import updated_reference
from jsar.redetect.search import Candidate
from jsar.tracking.jsar_tracker import JsarTracker, Localisation
from jsar.tracking.translation import TranslationFilter

# A turned window's warp and features cost about two upright windows' (docs/results-cost.md): a split's weights.
TURNED_FEATURE_COST = 2.0
# A coasting commit (the core's ADMM and size update) costs about 4.5 upright windows (aarch64: 38 M against 8.2 M,
# docs/results-cost.md): the worker's head start when it makes the commit while the windows are scored.
COAST_COMMIT_COST = 4.5


class DecisionFilter:
    """The decision filter and its reference; `train` after each committed frame, `score_*` anywhere."""

    def __init__(self, params: JsarParams, core: JsarTracker, rise_rate: float, fall_rate: float) -> None:
        translation = core.translation
        self.params = params
        self.rise_rate, self.fall_rate = rise_rate, fall_rate  # the reference's rates towards higher / lower peaks
        self.filter = TranslationFilter(params, translation.shape_hw, core.target_cells())
        self.filter.filter_f = translation.filter_f  # trained on the same first sample (mu = 0)
        # True while the decision filter has seen exactly the core's training history: then both are
        # the same STRCF solution and the core's is shared instead of solved again.
        self.in_sync = True
        self.reference: float | None = None

    def score_sample(self, sample_f: np.ndarray, centre_xy: tuple[float, float], side_px: float) -> Candidate:
        """The peak of the decision response to a detection sample spectrum (C, H, W//2+1) cut as a
        square of side_px centred on centre_xy px, and where it lies (px)."""
        response, response_f = self.filter.response(sample_f)
        dy, dx, peak = dcf.subpixel_peak(response, response_f, self.params.newton_iterations)
        px_per_cell = side_px / self.filter.shape_hw[0]
        return Candidate(centre_xy[0] + dx * px_per_cell, centre_xy[1] + dy * px_per_cell, float(peak),
                         window_xy=(float(centre_xy[0]), float(centre_xy[1])))

    def score_detection(self, loc: Localisation, core: JsarTracker) -> Candidate:
        """score_sample on the core's detection `loc` (before the core moves). While this filter is the core's own
        (in sync: the same filter_f object) its response on the core's sample is the one the core's locate found
        its peak on, so that peak is the score, not computed a second time: the same bits either way."""
        shared = (self.filter.filter_f is core.translation.filter_f
                  and self.filter.shape_hw == core.translation.shape_hw
                  and self.params.newton_iterations == core.params.newton_iterations and loc.scale_factor == 1.0)
        if not shared:
            return self.score_sample(loc.sample_f, core.centre_xy, loc.search_side)
        return Candidate(loc.centre_xy[0], loc.centre_xy[1], float(loc.peak),
                         window_xy=(float(core.centre_xy[0]), float(core.centre_xy[1])))

    def score_windows(self, image: np.ndarray, colour_table: np.ndarray | None, centres_xy: np.ndarray,
                      target_side_px: float, angles_deg: np.ndarray | None = None,
                      worker: concurrent.futures.Executor | None = None, worker_busy: float = 0.0) -> list[Candidate]:
        """Candidates (peak position px, raw peak, angle) of windows of the filter's sample geometry for a
        target of side target_side_px centred on centres_xy (N, 2) px, each scored with the image turned by
        angles_deg (N,) degrees about its centre (cv2's sign: counter-clockwise as displayed; 0 or None:
        upright). Upright windows are centred to the nearest cell of one shared feature map (centres on
        the same cell share a window); a turned window's peak is mapped back to the unturned image. The
        windows go through the window, FFT and correlation chain a cache-sized chunk at a time
        (dcf.window_response_spectra). Order: the upright candidates (by cell), then the turned ones as given.
        With `worker` (a one-thread executor on another core) part of the turned windows' patches and
        features are made there meanwhile (worker_share; worker_busy: the work already queued there, in upright
        windows): the same numbers."""
        centres_xy = np.asarray(centres_xy, dtype=np.float64).reshape(-1, 2)
        angles = np.zeros(len(centres_xy)) if angles_deg is None else np.asarray(angles_deg, dtype=np.float64)
        if angles.shape != (len(centres_xy),):
            raise ValueError(f"angles_deg must have one angle per centre, got {angles.shape} for {len(centres_xy)}")
        if len(centres_xy) == 0:
            return []
        cells, cell_size = self.filter.shape_hw[0], self.params.cell_size
        px_per_cell = self.params.search_area_factor * target_side_px / cells
        upright = angles == 0
        turned_order = np.flatnonzero(~upright)

        def turned_features(indices: list[int]) -> list[np.ndarray]:
            return [translation_features.extract_features(
                turned_patch(image, (float(centres_xy[k, 0]), float(centres_xy[k, 1])), cells * px_per_cell,
                             cells * cell_size, float(angles[k])), cell_size, colour_table) for k in indices]
        theirs = worker_share(int(upright.sum()), turned_order, worker_busy) if worker is not None else []
        mine = [int(k) for k in turned_order if int(k) not in theirs]
        job = worker.submit(turned_features, theirs) if worker is not None and theirs else None
        windows: list[np.ndarray] = []  # (H, W, C) float32 each, the upright ones views of one feature map
        window_centres, turns = [], []
        if upright.any():
            upright_windows, upright_centres = window_features(image, colour_table, centres_xy[upright], px_per_cell,
                                                               cells, cell_size)
            windows.extend(upright_windows)
            window_centres.extend(upright_centres)
            turns.extend([0.0] * len(upright_centres))
        turned = dict(zip(mine, turned_features(mine)))
        turned.update(zip(theirs, job.result() if job is not None else []))
        windows.extend(turned[int(k)] for k in turned_order)
        window_centres.extend(centres_xy[~upright])
        turns.extend(float(degrees) for degrees in angles[~upright])
        # Channels last throughout: moving the channels first for the FFT copied the whole stack once more
        # (docs/results-tracker.md, "Speed: where the time goes"); the spectra and responses are the same numbers.
        assert self.filter.filter_f is not None
        response_f = dcf.window_response_spectra(self.filter.filter_f, windows,
                                                 self.filter.cos_window)  # (M, H, W//2+1)
        responses = fourier.irfft2(response_f, self.filter.shape_hw)
        found = []
        for k, (centre, degrees) in enumerate(zip(window_centres, turns)):
            dy, dx, peak = dcf.subpixel_peak(responses[k], response_f[k], self.params.newton_iterations)
            offset = np.array([dx, dy]) * px_per_cell
            if degrees:
                # The window was turned by `degrees` about its centre: turn the offset back.
                offset = cv2.getRotationMatrix2D((0.0, 0.0), -degrees, 1.0)[:, :2] @ offset
            found.append(Candidate(float(centre[0] + offset[0]), float(centre[1] + offset[1]), float(peak), degrees,
                                   (float(centre[0]), float(centre[1]))))
        return found

    def train(self, core: JsarTracker, own_peak: float) -> None:
        """Learn the core's last training sample (a reliable committed frame); own_peak is this
        filter's peak on that frame's detection sample (updates the reference)."""
        self.reference = updated_reference(self.reference, own_peak, self.rise_rate, self.fall_rate)
        if self.in_sync:
            # Same previous filter, same sample, label and windows -> the same STRCF solution.
            self.filter.filter_f = core.translation.filter_f
            self.filter.reg_window = core.translation.reg_window
            return
        sample_f = core.last_training_sample_f
        assert sample_f is not None
        self.filter.set_target_cells(core.target_cells())
        self.filter.train(sample_f)

    def skip(self) -> None:
        """The core trained on a frame this filter does not learn: their histories part."""
        self.in_sync = False


def worker_share(upright_count: int, turned_indices: np.ndarray, worker_busy: float = 0.0) -> list[int]:
    """The turned windows (of `turned_indices`, in order) a second thread makes while this one makes the
    `upright_count` upright windows and the rest: each goes to the side with less work so far, a turned window
    costing TURNED_FEATURE_COST upright windows (ties: this thread), so that neither waits long for the other;
    worker_busy: the work (in upright windows) queued on the worker before them."""
    work = [float(upright_count), float(worker_busy)]  # this thread's, the worker's
    theirs = []
    for k in turned_indices:
        side = 1 if work[1] < work[0] else 0
        work[side] += TURNED_FEATURE_COST
        if side:
            theirs.append(int(k))
    return theirs


def turned_patch(image: np.ndarray, centre_xy: tuple[float, float], side_px: float, out_px: int,
                 degrees: float) -> np.ndarray:
    """uint8 (out_px, out_px[, 3]) patch: the square of side side_px centred on centre_xy px of `image`,
    turned by `degrees` about centre_xy (cv2's sign: counter-clockwise as displayed), borders
    replicated; resampled as patches.sample_patch does. A square larger than the output is shrunk first
    (shrunk_turned_patch); else only a canvas just covering it is warped, then enlarged."""
    if side_px > out_px:
        return shrunk_turned_patch(image, centre_xy, side_px, out_px, degrees)
    half = int(math.ceil(side_px / 2.0)) + 2
    x0, y0 = int(round(centre_xy[0])) - half, int(round(centre_xy[1])) - half  # the canvas origin (image px)
    turn = cv2.getRotationMatrix2D(centre_xy, degrees, 1.0)
    turn[:, 2] -= (x0, y0)  # turned image px -> canvas px
    canvas = cv2.warpAffine(image, turn, (2 * half + 1, 2 * half + 1), flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
    return patches.sample_patch(canvas, (centre_xy[0] - x0, centre_xy[1] - y0), (side_px, side_px), (out_px, out_px))


def shrunk_turned_patch(image: np.ndarray, centre_xy: tuple[float, float], side_px: float, out_px: int,
                        degrees: float) -> np.ndarray:
    """turned_patch for side_px > out_px: the square that holds the turned window is first area-averaged to the
    output's pixel size (patches.sample_patch), then turned there. Turning at the image's own resolution
    first cost a warp of the whole window (5-6 ms for a target of 180 px, whose 5-side window is 900 px);
    shrinking first reads the same pixels once and warps out_px^2. At 0 degrees it is sample_patch's patch."""
    scale = out_px / side_px  # output px per image px (< 1)
    radians = math.radians(degrees)
    cover_px = side_px * (abs(math.cos(radians)) + abs(math.sin(radians))) * scale  # the turned square's bound
    canvas_px = int(math.ceil(cover_px)) + 2  # + a pixel each side for the interpolation
    canvas_px += (canvas_px - out_px) % 2  # same parity: the output's pixel grid is the canvas's, shifted by whole pixels
    canvas = patches.sample_patch(image, centre_xy, (canvas_px / scale,) * 2, (canvas_px, canvas_px))
    # About the canvas centre (cv2 puts pixel k's centre at k), then the canvas centre onto the output's.
    centre = (canvas_px - 1) / 2.0
    turn = cv2.getRotationMatrix2D((centre, centre), degrees, 1.0)
    turn[:, 2] -= (canvas_px - out_px) / 2.0
    return cv2.warpAffine(canvas, turn, (out_px, out_px), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def window_features(image: np.ndarray, colour_table: np.ndarray | None, centres_xy: np.ndarray, px_per_cell: float,
                    cells: int, cell_size: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Translation features of M windows, each (cells, cells, C) float32, centred (to the nearest cell) on
    centres_xy (N, 2) px, M <= N (centres on the same cell share a window), and the window centres
    (M, 2) px. Cut (as views) from one feature map of the region covering every window when that is smaller
    than M separate windows, else one patch each."""
    half = cells // 2
    origin = centres_xy.min(axis=0) - (half + 1) * px_per_cell
    grid = np.unique(np.rint((centres_xy - origin) / px_per_cell).astype(np.int64), axis=0)
    window_centres = origin + grid * px_per_cell
    span = grid.max(axis=0) + half + 1  # (nx, ny) cells of the shared map
    if int(span[0]) * int(span[1]) <= len(grid) * cells * cells:
        size_px = span * px_per_cell
        patch = patches.sample_patch(image, tuple(origin + size_px / 2.0), tuple(size_px),
                                     (int(span[0]) * cell_size, int(span[1]) * cell_size))
        feature_map = translation_features.extract_features(patch, cell_size, colour_table)
        windows = [feature_map[cy - half:cy - half + cells, cx - half:cx - half + cells] for cx, cy in grid]
    else:
        side = cells * px_per_cell
        out = cells * cell_size
        windows = [translation_features.extract_features(
            patches.sample_patch(image, tuple(c), (side, side), (out, out)), cell_size, colour_table)
            for c in window_centres]
    return windows, window_centres
