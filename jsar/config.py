"""One typed configuration for JSAR, its STRCF baseline and JSAR-Re (paper table + method notes).

Units: sizes in pixels unless a name says cells; steps are multiplicative factors; thresholds on
response peaks are in the MATLAB FFT convention (forward DFT unnormalised, inverse scaled by 1/N),
which is the convention `jsar.dcf` uses, so the paper's values keep their meaning.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any


@dataclass(frozen=True)
class JsarParams:
    """Every tunable of the trackers; defaults = JSAR without re-detection (paper table + notes).

    `JsarParams.jsar_re()` gives the JSAR-Re variant (lambda 1, label sigma factor 0.054,
    size-label aspect sigma sqrt(13)*1.7), as the authors' JSAR-Re release sets them.

    Two size-filter defaults differ from the original, together: `size_subcell_peak` (the original
    takes the best grid cell) and `size_learning_rate` 0.03 (original 0.014). The label is nearly
    flat over the grid (sigma 5.4 of 13 cells), so the best cell stays the centre until the target
    has changed by about half a step, while the model meanwhile learns the wrong size. In the PX4
    closed loop (docs/sim.md, "Tests") a car that shrank while turning kept a box of 2.8x its area
    and was declared lost in plain view; with both changes the box follows it and the four PX4
    tracking checks pass. The learning rate alone did not fix that run; sub-cell alone lowered
    jsar-re's mean AUC on the shared sequences (docs/results-tracker.md, "Size filter: sub-cell estimate").
    Costs one fresh grid sample per frame: after a fractional step no cell of the old grid is reusable.

    `size_deadband_cells` (default 0: off) ignores a sub-cell offset smaller than this many grid cells
    per axis; 0.5 = move only when the best cell is not the centre, then by the refined amount. The
    sub-cell estimate has a cost over long runs: in the closed-loop soak the box of a car that keeps
    turning in-plane (not modelled: scale and aspect only) shrank steadily by ~0.25 % per frame, from
    0.48x to 0.10x the car's side in 21 s, then followed a patch of background. Measured with 0.5
    (2026-12-02): mean AUC on the shared sequences 0.567 (jsar-re) / 0.560 (jsar) against 0.556 / 0.554;
    the open-loop synthetic scene (`sim.export`, 180 s, seed 0) kept the car where the default lost it
    after 110 s; but the PX4 closed-loop centring test fails again (60.8 % centred, the lag above), so it
    is not the default. Where the target's range is known, the service bounds the box side instead
    (`set_side_bounds`, service.control.size_bound).
    """

    # --- features / search region (translation filter) ---
    cell_size: int = 4  # px per feature cell
    search_area_factor: float = 5.0  # search square side = factor * sqrt(w*h)
    search_patch_px: int = 200  # the search square is resampled to this side (px) -> 50x50 cells
    use_colour: bool = True  # colour-attribute channels on colour frames (42 ch), else 32
    colour_table_path: str | None = None  # external .npy (32768x10 or x11); None = derived table

    # --- translation filter (STRCF objective, ADMM) ---
    output_sigma_factor: float = 1.0 / 20.0  # label sigma = factor * sqrt(prod(floor(target/cell)))
    reg_window_inside: float = 1e-3  # spatial regularisation weight inside the target box
    reg_window_outside: float = 1e5  # ... and outside it
    admm_lambda: float = 1e-2  # spatial regularisation weight (MATLAB units, see dcf.admm_solve)
    admm_iterations: int = 4
    admm_penalty_init: float = 1.0  # ADMM penalty ("gamma" in STRCF's code)
    admm_penalty_growth: float = 10.0
    admm_penalty_max: float = 1e4
    temporal_mu: float = 16.0  # temporal regularisation weight (0 on the first frame)
    newton_iterations: int = 5  # sub-cell peak refinement on the Fourier-interpolated response

    # --- size filter (joint scale x aspect ratio, DSST-style 2-D filter) ---
    num_scales: int = 13  # S
    num_aspects: int = 13  # A
    scale_step: float = 1.03  # gamma: size multiplied by gamma^n along the scale axis
    aspect_step: float = 1.02  # phi: (w, h) -> (w * phi^n, h / phi^n): w/h ratio step phi^2
    size_learning_rate: float = 0.03  # the original's 0.014: see the class docstring
    size_lambda: float = 0.01
    size_model_max_area: float = 512.0  # px^2 (16 x 32), target aspect kept
    size_model_min_side: int = 8  # px: at least 2 fHOG cells per side for tiny targets
    size_sigma_scale: float = math.sqrt(13) * 1.5  # label sigma along the scale axis (grid cells)
    size_sigma_aspect: float = math.sqrt(13) * 1.5  # along the aspect axis (JSAR-Re: *1.7)
    size_subcell_peak: bool = True  # parabola-refined best cell (False: the original's best cell)
    size_deadband_cells: float = 0.0  # sub-cell: an offset below this (grid cells) is ignored; see the docstring
    size_grid_window: bool = False  # Hann window over the grid (DSST-style); off: see size_filter
    size_peak_rate: float = 0.1  # running mean of the size filter's response peaks (JsarTracker.hold_size_until_recognised)
    min_target_side_px: float = 3.0  # lower size clamp: a 6 px target must keep tracking
    aspect_band: float = 4.0  # w/h stays within [r0 / band, r0 * band], r0 = initial w/h

    # --- STRCF baseline's multi-scale search (translation filter on scaled samples) ---
    strcf_num_scales: int = 5
    strcf_scale_step: float = 1.01

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
        known = {f.name: f for f in fields(self)}
        for key, value in overrides.items():
            if key not in known:
                raise ValueError(f"unknown JsarParams key {key!r}")
            overrides[key] = _coerce(key, value, getattr(self, key))
        params = dataclasses.replace(self, **overrides)
        params.validate()
        return params

    def validate(self) -> None:
        """Raise ValueError naming the first parameter outside its valid range."""
        positive = [
            "cell_size", "search_area_factor", "search_patch_px", "output_sigma_factor",
            "reg_window_inside", "reg_window_outside", "admm_iterations", "admm_penalty_init",
            "admm_penalty_max", "num_scales", "num_aspects", "size_model_max_area",
            "size_model_min_side", "size_sigma_scale", "size_sigma_aspect", "min_target_side_px",
            "strcf_num_scales",
        ]
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        non_negative = ["admm_lambda", "temporal_mu", "newton_iterations", "size_lambda", "size_deadband_cells"]
        for name in non_negative:
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        at_least_one = ["admm_penalty_growth", "scale_step", "aspect_step", "aspect_band",
                        "strcf_scale_step"]
        for name in at_least_one:
            if not getattr(self, name) >= 1.0:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0.0 < self.size_learning_rate <= 1.0:
            raise ValueError(f"size_learning_rate must be in (0, 1], got {self.size_learning_rate}")
        if not 0.0 < self.size_peak_rate <= 1.0:
            raise ValueError(f"size_peak_rate must be in (0, 1], got {self.size_peak_rate}")
        if self.search_patch_px % self.cell_size:
            raise ValueError(
                f"search_patch_px ({self.search_patch_px}) must be a multiple of cell_size "
                f"({self.cell_size})")
        for name in ("num_scales", "num_aspects", "strcf_num_scales"):
            if getattr(self, name) % 2 == 0:
                raise ValueError(f"{name} must be odd (a centre sample), got {getattr(self, name)}")


def _coerce(key: str, value: Any, default: Any) -> Any:
    """`value` converted to the type of the field's default, or ValueError naming `key`."""
    if default is None or (isinstance(default, str) and value is None):
        if value is None or isinstance(value, str):
            return value
        raise ValueError(f"{key} must be a path string or None, got {value!r}")
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise ValueError(f"{key} must be a bool, got {value!r}")
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
            raise ValueError(f"{key} must be an integer, got {value!r}")
        return int(value)
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{key} must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ValueError(f"{key} must be finite, got {value!r}")
        return float(value)
    return value
