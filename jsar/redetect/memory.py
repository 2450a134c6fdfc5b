"""The decision filter: JSAR-Re's long-term memory of the target's reliable appearances.

A second STRCF translation filter (same features, geometry and solver as the core's), trained only
on reliable committed frames, never on a lost frame. It scores:
- the core tracker's own detection sample every frame (no extra features: one spectral product);
- windows of its sample geometry anywhere in the frame (the search while lost).
Scores are raw response peaks (MATLAB FFT convention, the paper's eta_d unit); positions full-frame
pixels. `reference` is the running mean of its peaks on the samples it trains on.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from jsar import dcf, fourier
from jsar.config import JsarParams
from jsar.features import patches
from jsar.features import translation as translation_features
from jsar.redetect.monitor import updated_reference
from jsar.redetect.search import Candidate
from jsar.tracking.jsar_tracker import JsarTracker
from jsar.tracking.translation import TranslationFilter

REFERENCE_RISE = 0.1  # the memory's reference follows higher peaks fast ...
REFERENCE_FALL = 0.02  # ... and lower ones slowly (as the monitor's)


class DecisionMemory:
    """The decision filter and its reference; `train` after each committed frame, `score_*` anywhere."""

    def __init__(self, params: JsarParams, core: JsarTracker) -> None:
        translation = core.translation
        self.params = params
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
        return Candidate(centre_xy[0] + dx * px_per_cell, centre_xy[1] + dy * px_per_cell, float(peak))

    def score_windows(self, image: np.ndarray, colour_table: np.ndarray | None, centres_xy: np.ndarray,
                      target_side_px: float) -> list[Candidate]:
        """Candidates (peak position px, raw peak) of windows of the filter's sample geometry for a
        target of side target_side_px, centred (to the nearest cell) on centres_xy (N, 2) px."""
        if len(centres_xy) == 0:
            return []
        cells = self.filter.shape_hw[0]
        px_per_cell = self.params.search_area_factor * target_side_px / cells
        windows, window_centres = window_features(image, colour_table, centres_xy, px_per_cell, cells,
                                                  self.params.cell_size)
        stack = np.moveaxis(windows, -1, 1) * self.filter.cos_window[None, None]
        spectra = fourier.rfft2(stack.astype(np.float32, copy=False))  # (M, C, H, W//2+1)
        assert self.filter.filter_f is not None
        response_f = np.einsum("chw,mchw->mhw", self.filter.filter_f.conj(), spectra)
        responses = fourier.irfft2(response_f, self.filter.shape_hw)
        found = []
        for k in range(len(responses)):
            dy, dx, peak = dcf.subpixel_peak(responses[k], response_f[k], self.params.newton_iterations)
            found.append(Candidate(window_centres[k, 0] + dx * px_per_cell, window_centres[k, 1] + dy * px_per_cell,
                                   float(peak)))
        return found

    def score_turned(self, image: np.ndarray, colour_table: np.ndarray | None, centre_xy: tuple[float, float],
                     target_side_px: float, degrees: float) -> Candidate:
        """The window on centre_xy px scored with the image turned by `degrees` about it (cv2's sign:
        counter-clockwise as displayed): a target that turned since the filter learnt it. The
        candidate's position is mapped back to the unturned image (px)."""
        side = self.params.search_area_factor * target_side_px
        half = int(math.ceil(side * math.sqrt(0.5))) + 2  # the turned window's corners stay inside the crop
        x0, y0 = int(round(centre_xy[0])) - half, int(round(centre_xy[1])) - half
        padded = cv2.copyMakeBorder(image, max(0, -y0), max(0, y0 + 2 * half + 1 - image.shape[0]),
                                    max(0, -x0), max(0, x0 + 2 * half + 1 - image.shape[1]), cv2.BORDER_REPLICATE)
        ox, oy = max(0, -x0), max(0, -y0)  # where the image's origin lies in the padded image
        crop = padded[oy + y0: oy + y0 + 2 * half + 1, ox + x0: ox + x0 + 2 * half + 1]
        pivot = (centre_xy[0] - x0, centre_xy[1] - y0)
        turn = cv2.getRotationMatrix2D(pivot, degrees, 1.0)
        turned = cv2.warpAffine(crop, turn, (crop.shape[1], crop.shape[0]), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
        found = self.score_windows(turned, colour_table, np.array([pivot]), target_side_px)[0]
        back = cv2.invertAffineTransform(turn)
        x, y = back[:, :2] @ np.array([found.x, found.y]) + back[:, 2]
        return Candidate(float(x) + x0, float(y) + y0, found.score)

    def train(self, core: JsarTracker, own_peak: float) -> None:
        """Learn the core's last training sample (a reliable committed frame); own_peak is this
        filter's peak on that frame's detection sample (updates the reference)."""
        self.reference = updated_reference(self.reference, own_peak, REFERENCE_RISE, REFERENCE_FALL)
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


def window_features(image: np.ndarray, colour_table: np.ndarray | None, centres_xy: np.ndarray, px_per_cell: float,
                    cells: int, cell_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Translation features (M, cells, cells, C) float32 of windows centred (to the nearest cell) on
    centres_xy (N, 2) px, M <= N (centres on the same cell share a window), and the window centres
    (M, 2) px. Cut from one feature map of the region covering every window when that is smaller
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
        windows = np.stack([feature_map[cy - half:cy - half + cells, cx - half:cx - half + cells]
                            for cx, cy in grid])
    else:
        side = cells * px_per_cell
        out = cells * cell_size
        windows = np.stack([translation_features.extract_features(
            patches.sample_patch(image, tuple(c), (side, side), (out, out)), cell_size, colour_table)
            for c in window_centres])
    return windows, window_centres
