"""One typed configuration for JSAR, its STRCF baseline and JSAR-Re's core (paper table + method notes).

Units: sizes in pixels unless a name says cells; steps are multiplicative factors; thresholds on
response peaks are in the MATLAB FFT convention (forward DFT unnormalised, inverse scaled by 1/N),
which is the convention `jsar.dcf` uses, so the paper's values keep their meaning.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from jsar.checked import Relation, at_least, check_fields, checked, interval, non_negative, odd, positive, with_overrides

RATE = interval(0, 1, low_open=True)  # a learning rate in (0, 1]


def _whole_cells(patch_px: int, params: "JsarParams") -> str | None:
    if patch_px % params.cell_size == 0:
        return None
    return f"must be a multiple of cell_size ({params.cell_size}), got {patch_px}"


@dataclass(frozen=True)
class JsarParams:
    """Every tunable of the core trackers; defaults = JSAR without re-detection (paper table + docs/method.md).

    `JsarParams.jsar_re()` gives the JSAR-Re variant, as the authors' JSAR-Re release sets it."""

    # --- features / search region (translation filter) ---
    cell_size: int = checked(4, positive)  # px per feature cell
    search_area_factor: float = checked(5.0, positive)  # search square side = this x sqrt(w*h)
    search_patch_px: int = checked(200, positive, Relation(_whole_cells))  # the search square is resampled to this side (px; 50x50 cells)
    use_colour: bool = True  # colour-attribute channels on colour frames (42 ch), else 32
    colour_table_path: str | None = None  # external .npy colour table (32768x10 or x11); None: the derived table

    # --- translation filter (STRCF objective, ADMM) ---
    output_sigma_factor: float = checked(1.0 / 20.0, positive)  # label sigma = this x sqrt(prod(floor(target/cell))) (cells)
    reg_window_inside: float = checked(1e-3, positive)  # spatial regularisation weight inside the target box
    reg_window_outside: float = checked(1e5, positive)  # spatial regularisation weight outside the target box
    admm_lambda: float = checked(1e-2, non_negative)  # lambda: spatial regularisation weight (MATLAB units, see dcf.admm_solve)
    admm_iterations: int = checked(4, positive)  # ADMM iterations per frame
    admm_penalty_init: float = checked(1.0, positive)  # ADMM penalty's start ("gamma" in STRCF's code)
    admm_penalty_growth: float = checked(10.0, at_least(1))  # ADMM penalty's growth factor per iteration
    admm_penalty_max: float = checked(1e4, positive)  # ADMM penalty's bound
    temporal_mu: float = checked(16.0, non_negative)  # mu: temporal regularisation weight (0 on the first frame)
    newton_iterations: int = checked(5, non_negative)  # sub-cell peak refinement steps on the Fourier-interpolated response

    # --- size filter (joint scale x aspect ratio, DSST-style 2-D filter) ---
    num_scales: int = checked(13, positive, odd)  # S: scales on the size grid
    num_aspects: int = checked(13, positive, odd)  # A: aspect ratios on the size grid
    scale_step: float = checked(1.03, at_least(1))  # gamma: size multiplied by gamma^n along the scale axis
    aspect_step: float = checked(1.02, at_least(1))  # phi: (w, h) -> (w * phi^n, h / phi^n), w/h ratio step phi^2
    size_learning_rate: float = checked(0.03, RATE)  # size filter's learning rate (the original's 0.014: docs/method.md)
    size_lambda: float = checked(0.01, non_negative)  # size filter's regularisation weight
    size_model_max_area: float = checked(512.0, positive)  # size model's sample area bound (px^2, 16 x 32), aspect kept
    size_model_min_side: int = checked(8, positive)  # size model's smallest sample side (px): 2 fHOG cells for tiny targets
    size_sigma_scale: float = checked(math.sqrt(13) * 1.5, positive)  # size label sigma along the scale axis (grid cells)
    size_sigma_aspect: float = checked(math.sqrt(13) * 1.5, positive)  # size label sigma along the aspect axis (grid cells; JSAR-Re: x1.7/1.5)
    size_subcell_peak: bool = True  # parabola-refined best grid cell (False: the original's best cell; docs/method.md)
    size_deadband_cells: float = checked(0.0, non_negative)  # a sub-cell size offset below this (grid cells) is ignored (0: off; docs/method.md)
    size_grid_window: bool = False  # Hann window over the size grid (DSST-style); off: see size_filter
    size_peak_rate: float = checked(0.1, RATE)  # running mean rate of the size filter's peaks (JsarTracker.hold_size_until_recognised)
    min_target_side_px: float = checked(3.0, positive)  # lower size clamp (px): a 6 px target must keep tracking
    aspect_band: float = checked(4.0, at_least(1))  # w/h stays within [r0 / band, r0 * band], r0 = initial w/h

    # --- STRCF baseline's multi-scale search (translation filter on scaled samples) ---
    strcf_num_scales: int = checked(5, positive, odd)  # STRCF's scales per frame
    strcf_scale_step: float = checked(1.01, at_least(1))  # STRCF's scale step

    @classmethod
    def jsar_re(cls, **overrides: Any) -> "JsarParams":
        """The JSAR-Re defaults (lambda 1, sigma factor 0.054, aspect sigma sqrt(13)*1.7) + overrides.
        JSAR-Re's own parameters (monitor, search, acceptance) are jsar.redetect.params.RedetectParams."""
        base = cls(
            admm_lambda=1.0,
            output_sigma_factor=0.054,
            size_sigma_aspect=math.sqrt(13) * 1.7,
        )
        return base.with_overrides(**overrides)

    def with_overrides(self, **overrides: Any) -> "JsarParams":
        """A copy with `overrides` applied; ValueError naming an unknown key or an invalid value."""
        params = with_overrides(self, overrides, "", unknown=lambda key: f"unknown JsarParams key {key!r}")
        params.validate()
        return params

    def validate(self) -> None:
        """ValueError naming the first parameter outside its valid range."""
        check_fields(self)
